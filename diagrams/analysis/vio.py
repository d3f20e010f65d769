"""Evaluates a VIO run (`alight vio-eval`): ATE, RPE per metre, processing times; TUM files for
evo."""
from pathlib import Path

import numpy as np

from alight.systems.vio.metrics import ate_rmse, rpe_per_metre, write_tum


def evaluate_vio(run, until: float | None = None) -> dict:
    """ATE and RPE per metre (evo's definitions, `systems/vio/metrics`) of the valid VIO estimate
    against the ground truth (up to the time `until` if given, e.g. a landing's touchdown),
    processing times (the `timing` stream of the system "vio": front end per frame, back end per
    keyframe); writes the TUM files into the run folder."""
    estimate = run["vio_estimate"]
    window = np.ones(len(estimate), bool) if until is None else \
        estimate["time"].to_numpy() <= until
    valid = (estimate["valid"].to_numpy() > 0.5) & window
    t = estimate["time"].to_numpy()[valid]
    p = run.field("vio_estimate", "p_EB").to_numpy()[valid]
    q = run.field("vio_estimate", "q_EB").to_numpy()[valid]
    truth = run["ground_truth"]
    p_true = np.column_stack([np.interp(t, truth["time"], truth[f"p_WB_{i}"]) for i in range(3)])
    q_true = run.field("ground_truth", "q_WB").to_numpy()[
        np.clip(np.searchsorted(truth["time"].to_numpy(), t), 0, len(truth) - 1)]
    write_tum(Path(run.path) / "vio_estimate.tum", t, p, q)
    write_tum(Path(run.path) / "ground_truth.tum", t, p_true, q_true)
    odometry = run["vio_odometry"]
    backend = run.compute_seconds("vio", "backend")
    travelled = float(np.linalg.norm(np.diff(p_true, axis=0), axis=1).sum())
    return {"valid_fraction": float(valid.sum() / max(window.sum(), 1)),
            "ate_rmse": ate_rmse(p, p_true),
            "rpe_per_m": rpe_per_metre(p, q, p_true, q_true, 1.0),
            "final_drift": float(np.linalg.norm(p[-1] - p_true[-1]) / max(travelled, 1e-9)),
            "travelled": travelled,
            "frontend_ms": float(run.compute_seconds("vio", "frontend").mean() * 1e3),
            "backend_ms": float(backend.mean() * 1e3), "backend_max_ms": float(backend.max() * 1e3),
            "restarts": int(odometry["restarts"].max()), "run_folder": str(run.path)}
