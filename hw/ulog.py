"""Reading PX4 flight logs (ULog, via pyulog) for identification of the attitude loop L(12).

The attitude setpoint (`vehicle_attitude_setpoint.q_d`) and the estimated attitude
(`vehicle_attitude.q`) are NED/FRD quaternions; they are converted to DESIGN.md's frames here
(alight.hw.frames) and resampled on one clock: the setpoint zero-order held, the attitude
interpolated.
"""
from pathlib import Path

import numpy as np

from alight.hw.frames import q_nf_to_wb
from alight.systems.control.identification import AxisData, IdentificationError
from alight.systems.control.linear_model import euler_pitch_roll_yaw

TOPICS = {"vehicle_attitude": [f"q[{i}]" for i in range(4)],
          "vehicle_attitude_setpoint": [f"q_d[{i}]" for i in range(4)]}


def load_ulog(path: str | Path):
    from pyulog import ULog
    path = Path(path)
    if not path.is_file():
        raise IdentificationError(f"{path}: no such log file")
    try:
        return ULog(str(path), message_name_filter_list=list(TOPICS))
    except Exception as e:  # pyulog raises various errors on corrupt files
        raise IdentificationError(f"{path}: not a readable ULog file ({e})") from None


def _topic(ulog, name: str) -> tuple[np.ndarray, np.ndarray]:
    """Timestamps [s] and (n, 4) quaternions of a topic; IdentificationError names what is missing."""
    datasets = [d for d in ulog.data_list if d.name == name]
    if not datasets:
        present = sorted({d.name for d in ulog.data_list})
        raise IdentificationError(f"the log has no '{name}' topic (needed: {sorted(TOPICS)}; "
                                  f"present: {present})")
    data = datasets[0].data
    missing = [f for f in TOPICS[name] if f not in data]
    if missing:
        raise IdentificationError(f"the log's '{name}' topic lacks fields {missing}")
    q = np.stack([data[f] for f in TOPICS[name]], axis=1).astype(float)
    keep = np.all(np.isfinite(q), axis=1) & (np.linalg.norm(q, axis=1) > 0.5)
    return data["timestamp"][keep] * 1e-6, q[keep]


def attitude_data_from_ulog(ulog, dt: float = 0.01) -> AxisData:
    """Commanded and estimated pitch/roll of a PX4 log on a uniform clock (W/B frames)."""
    t_sp, q_sp = _topic(ulog, "vehicle_attitude_setpoint")
    t_att, q_att = _topic(ulog, "vehicle_attitude")
    start, end = max(t_sp[0], t_att[0]), min(t_sp[-1], t_att[-1])
    if end - start < 50 * dt:
        raise IdentificationError(f"the setpoint and attitude topics overlap for only "
                                  f"{max(end - start, 0):.2f} s")
    t = np.arange(start, end, dt)
    held = np.clip(np.searchsorted(t_sp, t, side="right") - 1, 0, len(t_sp) - 1)
    reference = np.array([euler_pitch_roll_yaw(q_nf_to_wb(q))[:2] for q in q_sp[held]])
    measured = np.array([euler_pitch_roll_yaw(q_nf_to_wb(q))[:2] for q in q_att])
    pitch = np.interp(t, t_att, measured[:, 0])
    roll = np.interp(t, t_att, measured[:, 1])
    return AxisData(dt, reference[:, 0], reference[:, 1], pitch, roll)
