"""System identification of the landing paper's model, L Sec. 6.1 (`alight sysid`): the maths and
the plots.

The excitation flights (diagrams/running/sysid.py) give a fit set (each axis alone) and a
validation set (all axes at once), flown by the pilot-like ExcitationPilot through the
attitude+thrust interface with mocap odometry; the fit L(11)-(12) is reported as VAF per signal on
the validation set with a plot like L Fig. 6. PX4 logs: the attitude model L(12) from
`vehicle_attitude_setpoint` and `vehicle_attitude`.
"""
import dataclasses as dc
from pathlib import Path

import numpy as np

from alight.diagrams.running.run_log import RunLog
from alight.systems.control.identification import (AxisData, check_excitation,
                                                   damped_velocity_windows, fit_attitude_axis,
                                                   fit_damping, simulate_attitude, vaf)
from alight.systems.control.linear_model import (GRAVITY, LinearModelParams, euler_pitch_roll_yaw,
                                                 rotate_to_navigation)
from alight.systems.thrust_curve import ThrustCurve

SIGNALS = ("pitch", "roll", "vx", "vy", "vz")


def axis_data(run: RunLog, t_start: float, t_end: float, mass: float, curve: ThrustCurve,
              dt: float = 0.02) -> AxisData:
    """Uniformly resampled commanded and measured signals of a run between two times."""
    t = np.arange(t_start, t_end, dt)
    command = run["fc_command"]
    held = np.searchsorted(command["time"].to_numpy(), t, side="right") - 1  # zero-order hold
    q_ref = run.field("fc_command", "q_WD").to_numpy()[held]
    estimate = run["state_estimate"]
    te = estimate["time"].to_numpy()
    interp = lambda column: np.interp(t, te, estimate[column].to_numpy())
    q = np.stack([interp(f"q_EB_{i}") for i in range(4)], axis=1)
    v_W = np.stack([interp(f"v_EB_{i}") for i in range(3)], axis=1)
    ref_angles = np.array([euler_pitch_roll_yaw(x)[:2] for x in q_ref])
    angles = np.array([euler_pitch_roll_yaw(x) for x in q])
    v_N = np.array([rotate_to_navigation(v, yaw) for v, yaw in zip(v_W, angles[:, 2])])
    thrust = command["thrust"].to_numpy()[held]
    tilt = np.cos(angles[:, 0]) * np.cos(angles[:, 1])
    thrust_acc = curve.force(thrust) * tilt / mass - GRAVITY
    return AxisData(dt, ref_angles[:, 0], ref_angles[:, 1], angles[:, 0], angles[:, 1], v_N,
                    thrust_acc)


def _velocity_drives(data: AxisData) -> np.ndarray:
    """The inputs of L(11) per axis: g theta, -g phi, T (measured attitude, commanded thrust)."""
    return np.stack([GRAVITY * data.pitch, -GRAVITY * data.roll, data.thrust_acc], axis=1)


def simulate_signals(params: LinearModelParams, data: AxisData) -> dict[str, np.ndarray]:
    """The model's response to the data's inputs: attitude from the commands over the whole record,
    velocities from the measured attitude over 5 s windows restarted at the measured velocity."""
    rate = lambda angle: (angle[1] - angle[0]) / data.dt
    out = {"pitch": simulate_attitude(params.pitch, data.pitch_ref, data.dt,
                                      (data.pitch[0], rate(data.pitch))),
           "roll": simulate_attitude(params.roll, data.roll_ref, data.dt,
                                     (data.roll[0], rate(data.roll)))}
    drives = _velocity_drives(data)
    for axis, (name, c) in enumerate((("vx", params.c_x), ("vy", params.c_y),
                                      ("vz", params.c_z))):
        out[name] = damped_velocity_windows(c, drives[:, axis], data.velocity_N[:, axis], data.dt)
    return out


def measured_signals(data: AxisData) -> dict[str, np.ndarray]:
    return {"pitch": data.pitch, "roll": data.roll, "vx": data.velocity_N[:, 0],
            "vy": data.velocity_N[:, 1], "vz": data.velocity_N[:, 2]}


@dc.dataclass
class SysidReport:
    params: LinearModelParams
    vaf: dict[str, float]                 # per signal, on the validation set
    validation: AxisData
    simulated: dict[str, np.ndarray]
    fit: dict[str, AxisData] = dc.field(default_factory=dict)  # 'pitch', 'roll', 'thrust' data

    def lines(self) -> list[str]:
        p = self.params
        return ["identified L(11)-(12):",
                f"  c_x {p.c_x:.3f}  c_y {p.c_y:.3f}  c_z {p.c_z:.3f}  [1/s]",
                *(f"  {name:5s} stiffness {m.stiffness:7.2f}  damping {m.damping:6.2f}  gain "
                  f"{m.gain:7.2f}  (DC gain {m.dc_gain():.3f})"
                  for name, m in (("pitch", p.pitch), ("roll", p.roll))),
                "validation VAF: " + "  ".join(f"{k} {100 * v:.1f} %" for k, v in
                                               self.vaf.items())]


def identify(fit: dict[str, AxisData], validation: AxisData, mass: float,
             curve: ThrustCurve) -> SysidReport:
    """Fits pitch/roll L(12) and c_x, c_y, c_z L(11) on single-axis data, validates on `validation`.
    `fit` maps 'pitch', 'roll', 'thrust' to the data where that axis alone was excited."""
    pitch = fit_attitude_axis(fit["pitch"].pitch_ref, fit["pitch"].pitch, fit["pitch"].dt,
                              "pitch")
    roll = fit_attitude_axis(fit["roll"].roll_ref, fit["roll"].roll, fit["roll"].dt, "roll")
    damping = []
    for axis, key in ((0, "pitch"), (1, "roll"), (2, "thrust")):
        data = fit[key]
        # The thrust drive is the command (the motors' lag is unmeasured): search its delay.
        c, _ = fit_damping(_velocity_drives(data)[:, axis], data.velocity_N[:, axis], data.dt,
                           f"axis {axis}", max_delay=0.1 if axis == 2 else 0.0)
        damping.append(c)
    params = LinearModelParams(c_x=damping[0], c_y=damping[1], c_z=damping[2], pitch=pitch,
                               roll=roll, mass=mass, thrust_a=curve.a_t, thrust_b=curve.b_t)
    simulated = simulate_signals(params, validation)
    measured = measured_signals(validation)
    return SysidReport(params, {k: vaf(measured[k], simulated[k]) for k in SIGNALS}, validation,
                       simulated, fit)


def plot_validation(report: SysidReport, path: Path, title: str = "validation set") -> Path:
    """Measured vs model response per signal, like L Fig. 6."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    measured = measured_signals(report.validation) if report.validation.velocity_N is not None \
        else {"pitch": report.validation.pitch, "roll": report.validation.roll}
    names = [k for k in SIGNALS if k in report.simulated]
    t = np.arange(len(report.validation.pitch)) * report.validation.dt
    fig, axes = plt.subplots(len(names), 1, figsize=(9, 2 * len(names)), sharex=True)
    axes = np.atleast_1d(axes)
    units = {"pitch": "deg", "roll": "deg", "vx": "m/s", "vy": "m/s", "vz": "m/s"}
    for ax, name in zip(axes, names):
        scale = np.degrees(1.0) if units[name] == "deg" else 1.0
        ax.plot(t, scale * measured[name], label="measured")
        ax.plot(t, scale * report.simulated[name], "--", label="model")
        ax.set_ylabel(f"{name} [{units[name]}]")
        ax.set_title(f"VAF {100 * report.vaf[name]:.1f} %", fontsize=8, loc="right")
    axes[0].legend(loc="upper left")
    axes[0].set_title(title, fontsize=9, loc="left")
    axes[-1].set_xlabel("time [s]")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


@dc.dataclass
class AttitudeReport:
    """L(12) identified from a log, with VAF on the part of the log the fit did not use."""
    pitch: object
    roll: object
    vaf: dict[str, float]
    validation: AxisData
    simulated: dict[str, np.ndarray]

    def lines(self) -> list[str]:
        return ["identified L(12) from the log:",
                *(f"  {name:5s} stiffness {m.stiffness:7.2f}  damping {m.damping:6.2f}  gain "
                  f"{m.gain:7.2f}" for name, m in (("pitch", self.pitch), ("roll", self.roll))),
                "validation VAF: " + "  ".join(f"{k} {100 * v:.1f} %" for k, v in
                                               self.vaf.items())]


def identify_attitude(data: AxisData, fit_fraction: float = 0.6) -> AttitudeReport:
    """L(12) per axis fitted on the first part of a record and validated on the rest."""
    split = int(len(data.pitch) * fit_fraction)
    part = lambda s: AxisData(data.dt, data.pitch_ref[s], data.roll_ref[s], data.pitch[s],
                              data.roll[s])
    fit, validation = part(slice(0, split)), part(slice(split, None))
    pitch = fit_attitude_axis(fit.pitch_ref, fit.pitch, fit.dt, "pitch")
    roll = fit_attitude_axis(fit.roll_ref, fit.roll, fit.dt, "roll")
    for name, reference in (("pitch", validation.pitch_ref), ("roll", validation.roll_ref)):
        check_excitation(f"{name} reference in the validation part (the last "
                         f"{100 * (1 - fit_fraction):.0f} % of the log)", np.degrees(reference),
                         1.0, "deg")
    rate = lambda angle: (angle[1] - angle[0]) / data.dt
    simulated = {"pitch": simulate_attitude(pitch, validation.pitch_ref, data.dt,
                                            (validation.pitch[0], rate(validation.pitch))),
                 "roll": simulate_attitude(roll, validation.roll_ref, data.dt,
                                           (validation.roll[0], rate(validation.roll)))}
    scores = {"pitch": vaf(validation.pitch, simulated["pitch"]),
              "roll": vaf(validation.roll, simulated["roll"])}
    return AttitudeReport(pitch, roll, scores, validation, simulated)


def identify_from_ulog(path: Path, plot: Path | None = None) -> AttitudeReport:
    """L(12) from a PX4 log; IdentificationError names missing topics or missing excitation."""
    from alight.hw.ulog import attitude_data_from_ulog, load_ulog
    report = identify_attitude(attitude_data_from_ulog(load_ulog(path)))
    if plot is not None:
        plot_validation(report, plot, title=f"{Path(path).name}: validation part")
    return report
