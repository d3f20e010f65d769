"""Plots of one landing run: like L Fig. 10 (position, attitude and thrust against their references,
the background coloured by mission mode) and L Fig. 12 (3-D paths of the vehicle and the target)."""
from pathlib import Path

import numpy as np

from alight.diagrams.running.run_log import RunLog
from alight.systems.control.linear_model import euler_pitch_roll_yaw
from alight.systems.mission.landing import Mode

MODE_COLOURS = {Mode.TAKING_OFF: "#dddddd", Mode.WAYPOINT: "#cfe2f3", Mode.FOLLOW: "#d9ead3",
                Mode.LANDING_P1: "#fff2cc", Mode.LANDING_P2: "#fce5cd", Mode.LANDED: "#f4cccc"}


def _mode_spans(ax, run: RunLog) -> None:
    status = run["mission_status"]
    t, mode = status["time"].to_numpy(), status["mode"].to_numpy().astype(int)
    change = np.flatnonzero(np.diff(mode)) + 1
    starts = np.concatenate([[0], change])
    ends = np.concatenate([change, [len(t) - 1]])
    for s, e in zip(starts, ends):
        colour = MODE_COLOURS.get(Mode(mode[s]))
        if colour:
            ax.axvspan(t[s], t[e], color=colour, lw=0)


def plot_mission(run: RunLog, path: Path) -> Path:
    """L Fig. 10: x, y, z with their references; pitch, roll with the MPC's commands; thrust."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    truth, reference, command = run["ground_truth"], run["reference"], run["fc_command"]
    fig, axes = plt.subplots(6, 1, figsize=(10, 12), sharex=True)
    for i, name in enumerate("xyz"):
        ax = axes[i]
        _mode_spans(ax, run)
        ax.plot(truth["time"], truth[f"p_WB_{i}"], label="vehicle")
        ax.plot(reference["time"], reference[f"p_{i}"], "--", label="reference")
        ax.plot(truth["time"], truth[f"p_WT_{i}"], ":", label="target")
        ax.set_ylabel(f"{name} [m]")
    axes[0].legend(loc="upper left", fontsize=8)
    actual = np.degrees([euler_pitch_roll_yaw(q)[:2]
                         for q in run.field("ground_truth", "q_WB").to_numpy()])
    commanded = np.degrees([euler_pitch_roll_yaw(q)[:2]
                            for q in run.field("fc_command", "q_WD").to_numpy()])
    for i, name in enumerate(("pitch", "roll")):
        ax = axes[3 + i]
        _mode_spans(ax, run)
        ax.plot(truth["time"], actual[:, i], label="vehicle")
        ax.plot(command["time"], commanded[:, i], "--", label="MPC command")
        ax.set_ylabel(f"{name} [deg]")
    axes[3].legend(loc="upper left", fontsize=8)
    _mode_spans(axes[5], run)
    axes[5].plot(command["time"], command["thrust"], "--", label="command")
    axes[5].set_ylabel("thrust [0-1]")
    axes[5].set_xlabel("time [s] (background: taking off, waypoint, follow, landing 1, 2, landed)")
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


def plot_paths(run: RunLog, path: Path) -> Path:
    """L Fig. 12: the 3-D paths of the vehicle and the target."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    p_B = run.field("ground_truth", "p_WB").to_numpy()
    p_T = run.field("ground_truth", "p_WT").to_numpy()
    fig = plt.figure(figsize=(7, 6))
    ax = fig.add_subplot(projection="3d")
    ax.plot(*p_B.T, label="vehicle")
    ax.plot(*p_T.T, label="target (platform top)")
    ax.scatter(*p_B[-1], marker="x", color="k")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path
