"""Trajectory error metrics of the VIO evaluation (issue 8), following the `evo` package's
definitions: TUM-format export (`stamp tx ty tz qx qy qz qw`, so `evo_ape tum` / `evo_rpe tum` run
on the files), absolute trajectory error (position RMSE after an SE(3) Umeyama alignment of the
estimate to the ground truth, evo_ape --align), and relative pose error per metre travelled
(translation error of relative motions over `delta` metres of path, evo_rpe --delta --delta_unit m),
reported as a fraction of `delta` (drift).
"""
import numpy as np

from alight.systems.rotations import rotation_matrix


def write_tum(path, t: np.ndarray, p: np.ndarray, q_wxyz: np.ndarray) -> None:
    rows = np.column_stack([t, p, q_wxyz[:, 1:], q_wxyz[:, :1]])
    np.savetxt(path, rows, fmt="%.9f")


def umeyama_alignment(source: np.ndarray, target: np.ndarray):
    """R, t minimizing sum |target - (R source + t)|^2 (Umeyama 1991, no scale)."""
    mu_s, mu_t = source.mean(axis=0), target.mean(axis=0)
    cov = (target - mu_t).T @ (source - mu_s) / len(source)
    U, _, Vt = np.linalg.svd(cov)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1
    R = U @ S @ Vt
    return R, mu_t - R @ mu_s


def ate_rmse(p_est: np.ndarray, p_true: np.ndarray) -> float:
    R, t = umeyama_alignment(p_est, p_true)
    error = p_true - (p_est @ R.T + t)
    return float(np.sqrt(np.mean(np.sum(error ** 2, axis=1))))


def rpe_per_metre(p_est, q_est, p_true, q_true, delta: float = 1.0) -> float:
    """RMSE of the relative-pose translation error over pairs `delta` metres of true path apart,
    divided by `delta` (evo_rpe, delta_unit m, all pairs); NaN if the path is shorter."""
    travelled = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p_true, axis=0), axis=1))])
    errors = []
    for i in range(len(p_true)):
        j = np.searchsorted(travelled, travelled[i] + delta)
        if j >= len(p_true):
            break
        R_i_true, R_i_est = rotation_matrix(q_true[i]), rotation_matrix(q_est[i])
        rel_true = R_i_true.T @ (p_true[j] - p_true[i])
        rel_est = R_i_est.T @ (p_est[j] - p_est[i])
        errors.append(np.linalg.norm(rel_est - rel_true))
    return float(np.sqrt(np.mean(np.square(errors))) / delta) if errors else float("nan")
