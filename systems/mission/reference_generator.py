"""The landing paper's reference generation, L Sec. 6.3 and Fig. 8: the target position predicted
ahead by t_prediction with its estimated velocity (constant-velocity model, to counteract the
unmodelled delays of detection and control), then first-order low-pass filters on the reference
position and velocity (cut-off frequencies of L Table 2) against jittery target estimates.
"""
import numpy as np


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
