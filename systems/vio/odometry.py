"""Visual-inertial odometry as a Drake system (issue 8, L Sec. 5.1): the `VioEstimator` (front end,
GTSAM sliding window over L(3), IMU propagation) sampled at the IMU period.

The estimator holds a GTSAM smoother, which cannot live in a Drake context: like the MPC's OSQP
workspace it is a member of the system, reset by the initialization event; one system serves one
simulation at a time. Its outputs are discrete state, so they are reproducible from the context;
the front-end, back-end and propagation times go to its `compute_timer` (systems/timing.py),
outside it.
"""
import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem

from alight.systems.boundary import STATE_ESTIMATE, CameraFrame, ImuSamples, VectorLayout
from alight.systems.rotations import heading, rotation_matrix
from alight.systems.timing import ComputeTimer
from alight.systems.vio.estimator import VioEstimator, VioParams, VioStatus

# `odometry`: L(1) at the last camera frame: stamp [s]; status (VioStatus); p_WS [m], q_WS
# (w, x, y, z), v_WS [m/s] in the estimator frame E; gyro and accelerometer biases [rad/s, m/s^2];
# standard deviations of position, attitude (rotation vector in E) and velocity; keypoints in the
# frame; landmarks in the window; keyframes so far; stamp of the last keyframe [s]; window
# restarts after losses.
VIO_ODOMETRY = VectorLayout("vio_odometry", [
    ("stamp", 1), ("status", 1), ("p_WS", 3), ("q_WS", 4), ("v_WS", 3), ("b_g", 3), ("b_a", 3),
    ("std_p", 3), ("std_rot", 3), ("std_v", 3), ("tracked", 1), ("landmarks", 1),
    ("keyframes", 1), ("last_keyframe", 1), ("restarts", 1)])

VIO_FRAME_ID = 1.0  # the `frame_id` of the VIO's estimator frame in STATE_ESTIMATE (mocap is 0)
_NONE_USED = np.array([-1.0, -np.inf])  # no IMU sample (seq) and no camera frame (stamp) used yet
_NO_ESTIMATE = (VioStatus.INITIALIZING, VioStatus.LOST)  # reported invalid (enum members, looked
# up once: a class attribute lookup of an enum member is slow in Python 3.11)
_ODOMETRY_STATUS = VIO_ODOMETRY.slice("status").start
# The STATE_ESTIMATE fields set at every tick, written by slice into a preallocated vector; p_EB,
# v_EB, a_EB and q_EB are adjacent (`_KINEMATICS`), the ones that must be finite.
_FIELD = {field: STATE_ESTIMATE.slice(field) for field in (
    "stamp", "p_EB", "v_EB", "a_EB", "q_EB", "heading", "heading_rate", "var_pv", "var_heading",
    "p_EO")}
_KINEMATICS = slice(_FIELD["p_EB"].start, _FIELD["q_EB"].stop)
assert _KINEMATICS.stop - _KINEMATICS.start == 13, "p_EB, v_EB, a_EB, q_EB are not adjacent"
_VAR_P = slice(_FIELD["var_pv"].start, _FIELD["var_pv"].start + 3)
_VAR_V = slice(_FIELD["var_pv"].start + 3, _FIELD["var_pv"].stop)


class VisualInertialOdometry(LeafSystem):
    """Input  `imu`             ImuSamples (every sample is used once)
    Input  `rgbd`            CameraFrame of the forward RGB-D camera (geometric or rendered)
    Output `state_estimate`  STATE_ESTIMATE in E, IMU-propagated every `period` (valid 0 while
                             initializing or lost)
    Output `odometry`        VIO_ODOMETRY, updated with every camera frame and status change
    `compute_timer` records the front-end and back-end times (VioEstimator).
    """

    def __init__(self, params: VioParams):
        super().__init__()
        self._params = params
        self.compute_timer = ComputeTimer()
        self.estimator = VioEstimator(params, self.compute_timer)
        self._imu = self.DeclareAbstractInputPort("imu", AbstractValue.Make(ImuSamples.empty()))
        self._rgbd = self.DeclareAbstractInputPort("rgbd", AbstractValue.Make(CameraFrame()))
        self._estimate = self.DeclareDiscreteState(_invalid_estimate(stamp=0.0))
        self._odometry = self.DeclareDiscreteState(VIO_ODOMETRY.size)
        # the last IMU sample's seq and camera frame's stamp used (discrete state: Drake copies
        # abstract state with copy.deepcopy at every update)
        self._last = self.DeclareDiscreteState(_NONE_USED)
        # the valid state estimate's fields that never change; the rest is written every tick
        # (into this one array: the state takes a copy)
        self._valid_estimate = STATE_ESTIMATE.pack(
            stamp=0.0, p_EB=np.zeros(3), v_EB=np.zeros(3), a_EB=np.zeros(3), heading=0.0,
            heading_rate=0.0, var_pv=np.zeros(6), var_heading=0.0, frame_id=VIO_FRAME_ID,
            frame_counter=0.0, p_OldNew=np.zeros(3), q_OldNew=[1.0, 0.0, 0.0, 0.0], valid=1.0)
        self.DeclareInitializationUnrestrictedUpdateEvent(self._reset)
        self.DeclarePeriodicUnrestrictedUpdateEvent(params.period, 0.0, self._update)
        self.DeclareStateOutputPort("state_estimate", self._estimate)
        self.DeclareStateOutputPort("odometry", self._odometry)

    def _reset(self, context, state):
        self.estimator = VioEstimator(self._params, self.compute_timer)
        state.get_mutable_discrete_state(self._last).set_value(_NONE_USED)

    def _update(self, context, state):
        """The IMU samples, the new frame if any (the estimator times its front and back end),
        the propagated estimate; the rest of the tick is timed as part "propagation"."""
        seq, stamp = context.get_discrete_state(self._last).get_value()
        imu, frame = self._imu.Eval(context), self._rgbd.Eval(context)
        timer = self.compute_timer
        start, frame_seconds = timer.clock(), 0.0
        samples = imu.newer_than(int(seq))
        if len(samples):
            self.estimator.add_imu(samples)
            seq = int(samples.seq[-1])
        new_frame = frame.stamp > stamp and frame.valid  # (the cheap test first)
        if new_frame:
            frame_start = timer.clock()
            self.estimator.add_frame(frame)
            frame_seconds = timer.clock() - frame_start
            stamp = frame.stamp
        state.get_mutable_discrete_state(self._last).set_value([seq, stamp])
        estimate = self.estimator.estimate()
        state.get_mutable_discrete_state(self._estimate).set_value(
            self._state_estimate(context.get_time(), estimate))
        odometry = context.get_discrete_state(self._odometry).get_value()
        # (NumPy compares a float with an IntEnum member 50x slower than with a float)
        if new_frame or odometry[_ODOMETRY_STATUS] != float(self.estimator.status):
            state.get_mutable_discrete_state(self._odometry).set_value(
                self._odometry_vector(estimate))
        timer.record(context.get_time(), "propagation", timer.clock() - start - frame_seconds)

    def _state_estimate(self, t: float, estimate) -> np.ndarray:
        if estimate is None or self.estimator.status in _NO_ESTIMATE:
            return _invalid_estimate(stamp=t)
        vector = self._valid_estimate
        vector[_FIELD["p_EB"]] = estimate.p
        vector[_FIELD["v_EB"]] = estimate.v
        vector[_FIELD["a_EB"]] = estimate.a
        vector[_FIELD["q_EB"]] = estimate.q
        if not np.isfinite(vector[_KINEMATICS]).all():
            return _invalid_estimate(stamp=t)
        R = rotation_matrix(estimate.q)
        vector[_FIELD["stamp"]] = estimate.stamp
        vector[_FIELD["heading"]] = heading(R)
        vector[_FIELD["heading_rate"]] = (R @ estimate.w)[2]
        vector[_VAR_P] = estimate.var_p
        vector[_VAR_V] = estimate.var_v
        vector[_FIELD["var_heading"]] = estimate.var_rot[2]
        vector[_FIELD["p_EO"]] = self.estimator.correction
        return vector

    def _odometry_vector(self, estimate) -> np.ndarray:
        e, est = self.estimator, estimate
        window = e.window
        values = dict(stamp=np.nan, p_WS=np.nan, q_WS=np.nan, v_WS=np.nan, b_g=np.nan,
                      b_a=np.nan, std_p=np.nan, std_rot=np.nan, std_v=np.nan)
        if est is not None:
            values = dict(stamp=est.stamp, p_WS=est.p, q_WS=est.q, v_WS=est.v, b_g=est.b_g,
                          b_a=est.b_a, std_p=np.sqrt(est.var_p), std_rot=np.sqrt(est.var_rot),
                          std_v=np.sqrt(est.var_v))
        return VIO_ODOMETRY.pack(
            **values, status=float(e.status), tracked=e.tracked,
            landmarks=window.landmark_count() if window else 0,
            keyframes=window.keyframes if window else 0,
            last_keyframe=window.state.t if window and window.state else np.nan,
            restarts=e.restarts)


def _invalid_estimate(stamp: float) -> np.ndarray:
    return STATE_ESTIMATE.vector(stamp=stamp, var_pv=np.full(6, 1e6), var_heading=1e6,
                                 frame_id=VIO_FRAME_ID, valid=0.0)
