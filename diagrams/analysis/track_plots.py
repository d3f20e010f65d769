"""Plots of an `alight track` run folder, like M Fig. 7-13: position, velocity and acceleration
against the reference (steps), the x-y path and the heading (circle), and the tilt and speed under
estimator faults. Written as PNG files into the run folder."""
from pathlib import Path

import numpy as np

from alight.diagrams.running.run_log import RunLog
from alight.systems.rotations import tilt_deg


def plot_track(run: RunLog) -> list[Path]:
    """Writes `track.png` (states vs reference, estimate and truth) and, for the circle,
    `track_xy.png`; returns the written paths."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    truth, reference, estimate = run["ground_truth"], run["reference"], run["state_estimate"]
    t = truth["time"].to_numpy()
    p = run.field("ground_truth", "p_WB").to_numpy()
    v = run.field("ground_truth", "v_WB").to_numpy()
    p_d = run.field("reference", "p").to_numpy()
    p_e = run.field("state_estimate", "p_EB").to_numpy()
    q = run.field("ground_truth", "q_WB").to_numpy()
    eta = np.arctan2(2 * (q[:, 0] * q[:, 3] + q[:, 1] * q[:, 2]),
                     1 - 2 * (q[:, 2] ** 2 + q[:, 3] ** 2))
    written = []
    fig, axes = plt.subplots(5, 1, figsize=(9, 12), sharex=True)
    for i, axis in enumerate("xyz"):
        axes[i].plot(reference["time"], p_d[:, i], "k--", label="reference chi")
        axes[i].plot(estimate["time"], p_e[:, i], color="tab:orange", alpha=0.6, label="estimate x")
        axes[i].plot(t, p[:, i], color="tab:blue", label="ground truth x*")
        axes[i].set_ylabel(f"{axis} [m]")
    axes[0].legend(loc="upper right")
    axes[3].plot(t, np.linalg.norm(v, axis=1), label="speed [m/s]")
    axes[3].plot(t, np.degrees(np.unwrap(eta)), label="heading [deg]", alpha=0.7)
    axes[3].plot(reference["time"], np.degrees(np.unwrap(reference["heading"])), "k--",
                 label="reference heading [deg]")
    axes[3].legend(loc="upper right")
    axes[4].plot(t, tilt_deg(q))
    axes[4].set_ylabel("tilt [deg]")
    axes[4].set_xlabel("time [s]")
    marks = run.metadata.get("marks", {})
    for ax in axes:
        for mark in marks.values():
            ax.axvline(mark, color="grey", lw=0.5)
    experiment = run.metadata["experiment"]
    fig.suptitle(f"{experiment['trajectory']} with {', '.join(run.metadata['controllers'])}")
    fig.tight_layout()
    written.append(run.path / "track.png")
    fig.savefig(written[-1], dpi=80)
    plt.close(fig)
    if experiment["trajectory"] == "circle":
        fig, ax = plt.subplots(figsize=(6, 6))
        ax.plot(p_d[:, 0], p_d[:, 1], "k--", label="reference")
        ax.plot(p[:, 0], p[:, 1], label="ground truth")
        ax.set_aspect("equal")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.legend()
        written.append(run.path / "track_xy.png")
        fig.savefig(written[-1], dpi=80)
        plt.close(fig)
    return written
