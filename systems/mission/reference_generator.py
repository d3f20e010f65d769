"""The landing paper's reference generation, L Sec. 6.3 and Fig. 8: the target position predicted
ahead by t_prediction with its estimated velocity (constant-velocity model, to counteract the
unmodelled delays of detection and control), then first-order low-pass filters on the reference
position and velocity (cut-off frequencies of L Table 2) against jittery target estimates.

Beyond the paper: the target's horizontal acceleration, the low-passed rate of change of the
filtered velocity, is fed to the reference. The paper's reference moves on at constant velocity
over the MPC's horizon (L Sec. 6.3); on the MBZIRC figure eight (10 m turn radius at 4.2 m/s, a
1.7 m/s^2 centripetal acceleration) that straight extrapolation put every touchdown 32-41 cm
outside the curve (docs/benchmarks.md, issue 23).

Also beyond the paper: the lead for the level touchdown (alight.systems.control.touchdown_level).
Levelled for its last decimetres, the vehicle loses the horizontal acceleration its tilt held
against the air flowing over the moving car and drifts back by about a t^2 / 2 before the legs
touch (12 cm median at 5 m/s in 15 km/h wind, docs/landing.md "Level touchdown lead"); the
descending reference leads the target by that much, so the drift ends on the platform's centre.
"""
import numpy as np

from alight.systems.control.linear_model import GRAVITY
from alight.systems.rotations import all_finite, rotation_matrix


def predict_target(p_WT: np.ndarray, v_WT: np.ndarray, t_prediction: float) -> np.ndarray:
    """Target position t_prediction ahead, assuming constant velocity."""
    return np.asarray(p_WT) + t_prediction * np.asarray(v_WT)


def low_pass_gain(cutoff: float, period: float) -> float:
    """Gain of the discretized first-order low pass y += a (u - y) at `cutoff` [Hz]."""
    return float(1.0 - np.exp(-2.0 * np.pi * cutoff * period))


def filter_reference(previous_p, previous_v, p_WT, v_WT, t_prediction: float,
                     cutoff_position: float, cutoff_velocity: float,
                     period: float) -> tuple[np.ndarray, np.ndarray]:
    """One step of L Fig. 8: the new filtered reference position and velocity."""
    target = predict_target(p_WT, v_WT, t_prediction)
    a_p, a_v = low_pass_gain(cutoff_position, period), low_pass_gain(cutoff_velocity, period)
    p = np.asarray(previous_p) + a_p * (target - previous_p)
    v = np.asarray(previous_v) + a_v * (np.asarray(v_WT) - previous_v)
    return p, v


def filter_acceleration(previous_a, previous_v, v, cutoff: float, max_acceleration: float,
                        period: float) -> np.ndarray:
    """One step of the target acceleration's low pass at `cutoff` [Hz] toward the horizontal
    rate of change of the filtered velocity (`previous_v` to `v` over `period`), its norm
    clipped to `max_acceleration`; zero with cutoff 0 (the paper)."""
    if cutoff <= 0.0:
        return np.zeros(3)
    rate = (np.asarray(v, float) - previous_v) / period
    rate[2] = 0.0
    a = np.asarray(previous_a, float) + low_pass_gain(cutoff, period) * (rate - previous_a)
    size = float(np.linalg.norm(a))
    return a * (max_acceleration / size) if size > max_acceleration else a


def held_acceleration(q_EB, a_B) -> np.ndarray:
    """Horizontal acceleration [m/s^2] (z zero) the tilt holds against the air: g tan(tilt)
    toward the tilt (the thrust's at hover) less the vehicle's own acceleration a_B (the rate of
    its estimated velocity: the estimators' acceleration field is the mocap bank's twice
    differentiated position, +-10 m/s^2 of noise), so what levelling takes away, not the
    vehicle's manoeuvre (with the tilt alone, a vehicle behind and tilting forward to catch up
    led its own reference further ahead: 6 m/s, seed 9). Zero when tilted past 60 deg or not
    finite."""
    z_B = rotation_matrix(np.asarray(q_EB, float))[:, 2]
    a_B = np.asarray(a_B, float)
    if not (all_finite(z_B) and all_finite(a_B)) or z_B[2] < 0.5:
        return np.zeros(3)
    return np.array([GRAVITY * z_B[0] / z_B[2] - a_B[0], GRAVITY * z_B[1] / z_B[2] - a_B[1],
                     0.0])


def filter_held_acceleration(previous_a, previous_v, v_EB, q_EB, cutoff: float,
                             period: float) -> np.ndarray:
    """One step of the low pass at `cutoff` [Hz] toward `held_acceleration`, the vehicle's own
    acceleration the rate of its estimated velocity from `previous_v` to `v_EB` over `period`
    (zero while `previous_v` is not finite: the first step)."""
    previous_v = np.asarray(previous_v, float)
    a_B = (np.asarray(v_EB, float) - previous_v) / period if all_finite(previous_v) \
        else np.zeros(3)
    previous_a = np.asarray(previous_a, float)
    return previous_a + low_pass_gain(cutoff, period) * (held_acceleration(q_EB, a_B)
                                                         - previous_a)


def level_lead(a_held, lead_time: float, height: float, ramp_start: float, ramp_end: float,
               max_lead: float) -> np.ndarray:
    """Lead [m] of the descending reference for the level touchdown: a_held lead_time^2 / 2,
    ramped in linearly as `height` goes from `ramp_start` down to `ramp_end` (full below), its
    length at most `max_lead`."""
    span = ramp_start - ramp_end
    share = 1.0 if span <= 0.0 else float(np.clip((ramp_start - height) / span, 0.0, 1.0))
    lead = 0.5 * share * lead_time ** 2 * np.asarray(a_held, float)
    size = float(np.linalg.norm(lead))
    return lead * (max_lead / size) if size > max_lead else lead
