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
        new_frame = frame.valid and frame.stamp > stamp
        if new_frame:
            frame_start = timer.clock()
            self.estimator.add_frame(frame)
            frame_seconds = timer.clock() - frame_start
            stamp = frame.stamp
        state.get_mutable_discrete_state(self._last).set_value([seq, stamp])
        previous = context.get_discrete_state(self._estimate).get_value()
        estimate = self.estimator.estimate()
        state.get_mutable_discrete_state(self._estimate).set_value(
            self._state_estimate(context.get_time(), estimate, previous))
        odometry = context.get_discrete_state(self._odometry).get_value()
        if new_frame or VIO_ODOMETRY.get(odometry, "status") != self.estimator.status:
            state.get_mutable_discrete_state(self._odometry).set_value(
                self._odometry_vector(estimate))
        timer.record(context.get_time(), "propagation", timer.clock() - start - frame_seconds)

    def _state_estimate(self, t: float, estimate, previous) -> np.ndarray:
        status = self.estimator.status
        finite = estimate is not None and np.isfinite(
            np.concatenate([estimate.p, estimate.v, estimate.q, estimate.a])).all()
        if not finite or status in (VioStatus.INITIALIZING, VioStatus.LOST):
            return _invalid_estimate(stamp=t)
        R = rotation_matrix(estimate.q)
        return STATE_ESTIMATE.pack(
            stamp=estimate.stamp, p_EB=estimate.p, v_EB=estimate.v, a_EB=estimate.a,
            q_EB=estimate.q, heading=heading(R), heading_rate=(R @ estimate.w)[2],
            var_pv=np.concatenate([estimate.var_p, estimate.var_v]),
            var_heading=estimate.var_rot[2], frame_id=VIO_FRAME_ID, frame_counter=0.0,
            p_OldNew=np.zeros(3), q_OldNew=[1.0, 0.0, 0.0, 0.0], valid=1.0,
            p_EO=self.estimator.correction)

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
