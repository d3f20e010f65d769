"""What the companion computer tells PX4 about positions, as MAVLink messages: the state estimate
as external vision (ODOMETRY) and the landing target (LANDING_TARGET). Both ends use these
encoders and decoders: the MAVLink vehicle (hw/mavlink_vehicle.py) and `alight hil`
(hw/hil.py) send, the simulated autopilot (hw/sim_autopilot.py) reads as PX4's MAVLink receiver
does. Frame conversions come from hw/frames.py.

ODOMETRY, as PX4's "External Position Estimation" asks for VIO or mocap sent as vision: frame_id
MAV_FRAME_LOCAL_FRD (a local frame of arbitrary heading: the estimator frame E, z down), child
frame MAV_FRAME_BODY_FRD (the velocity in the body frame), pose and velocity covariance (upper
triangle of 6x6, row-major: x, y, z, roll, pitch, yaw), reset_counter (incremented when the
estimator's frame changes, so that EKF2 resets to the new frame instead of rejecting the jump),
estimator_type VISION or VIO (PX4 fuses these; MOCAP goes to another topic EKF2 does not read) and
quality (-1 failed, 1 worst .. 100 best).

LANDING_TARGET, as PX4's MAVLink receiver reads it: frame MAV_FRAME_LOCAL_NED with
position_valid = 1 and x, y, z the target's position in the local frame (PX4 copies them into
landing_target_pose.x_abs/y_abs/z_abs; any other frame with a valid position is refused).
"""
import math

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from alight.hw.frames import (body_variances, body_frd_to_world, ned_to_w, q_nf_to_wb,
                              q_wb_to_nf, w_to_ned, world_to_body_frd, world_variances)
from alight.systems.boundary import STATE_ESTIMATE, TARGET_ESTIMATE, VectorLayout
from alight.systems.rotations import heading, rotation_matrix

ESTIMATOR_TYPES = {"vision": mavlink.MAV_ESTIMATOR_TYPE_VISION,
                   "vio": mavlink.MAV_ESTIMATOR_TYPE_VIO}
# What PX4's receiver publishes as vehicle_visual_odometry (fused by EKF2): the local frames, and
# VISION, VIO or (legacy) UNKNOWN sources.
_VISION_FRAMES = (mavlink.MAV_FRAME_LOCAL_FRD, mavlink.MAV_FRAME_LOCAL_NED)
_VISION_SOURCES = (mavlink.MAV_ESTIMATOR_TYPE_VISION, mavlink.MAV_ESTIMATOR_TYPE_VIO,
                   mavlink.MAV_ESTIMATOR_TYPE_UNKNOWN)
# What a receiver of LANDING_TARGET logs (the simulated autopilot's run folder): the time it
# arrived [s, autopilot clock], the message's time (`sent`, the estimate's) [s], the target
# position p_WT [m, W] and the number received so far.
LANDING_TARGET_RECEIVED = VectorLayout("landing_target", [
    ("stamp", 1), ("sent", 1), ("p_WT", 3), ("count", 1)])
# Diagonal of the 6x6 covariance in its 21-element upper triangle: x, y, z, roll, pitch, yaw.
DIAGONAL = (0, 6, 11, 15, 18, 20)


def estimator_type(name: str) -> int:
    if name not in ESTIMATOR_TYPES:
        raise ValueError(f"odometry estimator type '{name}': one of {sorted(ESTIMATOR_TYPES)}")
    return ESTIMATOR_TYPES[name]


def quality(estimate: np.ndarray, worst_std: float) -> int:
    """ODOMETRY's quality of a STATE_ESTIMATE: -1 when invalid, else 100 for a perfect position
    falling linearly to 1 at a position standard deviation (the largest axis) of `worst_std`."""
    var_p = STATE_ESTIMATE.get(estimate, "var_pv")[:3]
    if STATE_ESTIMATE.get(estimate, "valid") < 0.5 or not np.all(np.isfinite(var_p)):
        return -1
    std = math.sqrt(max(float(np.max(var_p)), 0.0))
    return int(np.clip(round(100.0 * (1.0 - std / worst_std)), 1, 100))


def _covariance(diagonal) -> list[float]:
    values = [0.0] * 21
    for index, value in zip(DIAGONAL, diagonal):
        values[index] = float(value)
    return values


def odometry_message(mav, estimate: np.ndarray, time_usec: int, reset_counter: int,
                     source: int, quality_value: int, frame: int = mavlink.MAV_FRAME_LOCAL_FRD):
    """ODOMETRY of a STATE_ESTIMATE (position, orientation and velocity of B in E) stamped
    `time_usec` on the autopilot's clock, the pose in `frame` (LOCAL_FRD for external vision;
    PX4 sends its own in LOCAL_NED). Body rates are not estimated: NaN ("unknown")."""
    L = STATE_ESTIMATE
    q_EB = L.get(estimate, "q_EB")
    q_EB = q_EB / np.linalg.norm(q_EB)
    p_N = w_to_ned(L.get(estimate, "p_EB"))
    v_F = world_to_body_frd(L.get(estimate, "v_EB"), q_EB)
    var = L.get(estimate, "var_pv")
    var_heading = L.get(estimate, "var_heading")
    pose_covariance = _covariance([*var[:3], var_heading, var_heading, var_heading])
    velocity_covariance = _covariance([*body_variances(var[3:], q_EB), math.nan, math.nan,
                                       math.nan])
    return mav.odometry_encode(
        int(time_usec), frame, mavlink.MAV_FRAME_BODY_FRD,
        *[float(v) for v in p_N], [float(v) for v in q_wb_to_nf(q_EB)],
        *[float(v) for v in v_F], math.nan, math.nan, math.nan, pose_covariance,
        velocity_covariance, int(reset_counter) % 256, int(source), int(quality_value))


def decode_odometry(message) -> np.ndarray | None:
    """The STATE_ESTIMATE (in W, stamped on the autopilot's clock) of an ODOMETRY that PX4 would
    fuse as external vision, or None when PX4 would not (another frame or source, a non-finite
    pose). frame_counter is the message's reset_counter; valid is 0 when quality is -1. A
    velocity in an unknown child frame, or unknown variances, come out NaN (not fused)."""
    if message.frame_id not in _VISION_FRAMES or message.estimator_type not in _VISION_SOURCES:
        return None
    q = np.array(message.q, dtype=float)
    p_W = ned_to_w([message.x, message.y, message.z])
    if not (np.all(np.isfinite(q)) and np.all(np.isfinite(p_W))) or np.linalg.norm(q) < 0.5:
        return None
    q_WB = q_nf_to_wb(q / np.linalg.norm(q))
    v = [message.vx, message.vy, message.vz]
    if message.child_frame_id == mavlink.MAV_FRAME_BODY_FRD:
        v_W = body_frd_to_world(v, q_WB)
        var_v = world_variances([message.velocity_covariance[i] for i in DIAGONAL[:3]], q_WB)
    elif message.child_frame_id in _VISION_FRAMES:
        v_W = ned_to_w(v)
        var_v = np.array([message.velocity_covariance[i] for i in DIAGONAL[:3]])
    else:
        v_W, var_v = np.full(3, math.nan), np.full(3, math.nan)
    var_p = np.array([message.pose_covariance[i] for i in DIAGONAL[:3]], dtype=float)
    return STATE_ESTIMATE.vector(
        stamp=message.time_usec * 1e-6, p_EB=p_W, v_EB=v_W, q_EB=q_WB,
        heading=heading(rotation_matrix(q_WB)), var_pv=np.concatenate([var_p, var_v]),
        var_heading=message.pose_covariance[DIAGONAL[5]], frame_counter=message.reset_counter,
        valid=float(message.quality != -1))


def landing_target_message(mav, target: np.ndarray, estimate: np.ndarray, time_usec: int):
    """LANDING_TARGET of a TARGET_ESTIMATE (target T in the estimator frame E) for PX4's precision
    landing: MAV_FRAME_LOCAL_NED, position_valid 1, x, y, z the target's position in the local
    frame (the frame the ODOMETRY gives PX4), q its orientation. The angular form is filled from
    the target relative to the vehicle in FRD, as a down camera aligned with the body sees it:
    angle_x = atan2(y_F, z_F) (right of the centre), angle_y = atan2(-x_F, z_F) (image y points
    backwards), distance = |p_BT|."""
    p_ET = TARGET_ESTIMATE.get(target, "p_WT")
    q_EB = STATE_ESTIMATE.get(estimate, "q_EB")
    p_BT_F = world_to_body_frd(p_ET - STATE_ESTIMATE.get(estimate, "p_EB"),
                                   q_EB / np.linalg.norm(q_EB))
    q_ET = TARGET_ESTIMATE.get(target, "q_WT")
    return mav.landing_target_encode(
        int(time_usec), 0, mavlink.MAV_FRAME_LOCAL_NED,
        math.atan2(p_BT_F[1], p_BT_F[2]), math.atan2(-p_BT_F[0], p_BT_F[2]),
        float(np.linalg.norm(p_BT_F)), 0.0, 0.0, *[float(v) for v in w_to_ned(p_ET)],
        [float(v) for v in q_wb_to_nf(q_ET / np.linalg.norm(q_ET))],
        mavlink.LANDING_TARGET_TYPE_VISION_FIDUCIAL, 1)


def decode_landing_target(message) -> np.ndarray | None:
    """p_WT [m, W] of a LANDING_TARGET that PX4 would use (MAV_FRAME_LOCAL_NED, position_valid),
    else None."""
    if message.frame != mavlink.MAV_FRAME_LOCAL_NED or not message.position_valid:
        return None
    return ned_to_w([message.x, message.y, message.z])
