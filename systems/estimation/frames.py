"""Estimator frames, M Sec. 3.5 and 7.1: poses between the frames of the bank's hypotheses.

On a switch the bank reports X_OldNew (p_OldNew, q_OldNew), the pose of the new frame in the
old. `FrameAnchor` chains them into X_AE, the pose of the active frame E in the anchor frame A
(the frame active when the estimate first became valid), and re-expresses the estimate in A:
an estimate that never jumps when the arbiter switches, for consumers that do not re-express
their own states (today the landing paper's linear MPC and the waypoint mission; M Sec. 7.2
gives that job to the control manager, which then reads the bank's output directly).
"""
import numpy as np
from pydrake.systems.framework import LeafSystem

from alight.systems.boundary import STATE_ESTIMATE
from alight.systems.estimation.heading import wrap_angle
from alight.systems.rotations import heading, quaternion_product, rotation_matrix

# discrete state: [frame counter seen, anchored (0/1), p_AE (3), q_AE (4)]
_COUNTER, _ANCHORED, _P, _Q = 0, 1, slice(2, 5), slice(5, 9)
_FRAME_COUNTER = STATE_ESTIMATE.slice("frame_counter").start  # (read at every controller tick)


def compose(p_AB, q_AB, p_BC, q_BC) -> tuple[np.ndarray, np.ndarray]:
    """X_AC = X_AB X_BC for poses given as (p, q) with (w, x, y, z) quaternions."""
    return np.asarray(p_AB) + rotation_matrix(q_AB) @ np.asarray(p_BC), \
        quaternion_product(q_AB, q_BC)


def reexpress_point(p, R_OldNew: np.ndarray, p_OldNew: np.ndarray) -> np.ndarray:
    """Points of the old estimator frame in the new one (M Sec. 3.5): [x, y, z] or rows of them,
    p_new = R_OldNew^T (p_old - p_OldNew); a fourth column (a heading) loses the frames' yaw."""
    rows = np.array(p, float)
    rows[..., :3] = (rows[..., :3] - p_OldNew) @ R_OldNew
    if rows.shape[-1] > 3:
        rows[..., 3] -= heading(R_OldNew)
    return rows


def frame_switch(estimate: np.ndarray, frame_counter: float
                 ) -> tuple[np.ndarray, np.ndarray] | None:
    """(R_OldNew, p_OldNew) when the STATE_ESTIMATE `estimate` is in another estimator frame than
    the one of `frame_counter` (the arbiter switched, M Sec. 3.5); None in the same frame or
    when `frame_counter` is NaN (no frame yet)."""
    counter = estimate[_FRAME_COUNTER]
    if counter == frame_counter or not np.isfinite(frame_counter):
        return None
    return (rotation_matrix(STATE_ESTIMATE.get(estimate, "q_OldNew")),
            STATE_ESTIMATE.get(estimate, "p_OldNew"))


def reexpress(estimate: np.ndarray, p_AE, q_AE) -> np.ndarray:
    """A STATE_ESTIMATE in frame E expressed in frame A (frame fields left as they are)."""
    L = STATE_ESTIMATE
    R_AE = rotation_matrix(q_AE)
    out = np.array(estimate, float)
    out[L.slice("p_EB")] = p_AE + R_AE @ L.get(estimate, "p_EB")
    out[L.slice("v_EB")] = R_AE @ L.get(estimate, "v_EB")
    out[L.slice("a_EB")] = R_AE @ L.get(estimate, "a_EB")
    out[L.slice("q_EB")] = quaternion_product(q_AE, L.get(estimate, "q_EB"))
    out[L.slice("heading")] = wrap_angle(L.get(estimate, "heading") + heading(R_AE))
    var = L.get(estimate, "var_pv")  # heading offsets are small: keep per-axis variances
    out[L.slice("var_pv")] = np.concatenate([np.abs(R_AE) ** 2 @ var[:3],
                                             np.abs(R_AE) ** 2 @ var[3:]])
    return out


class FrameAnchor(LeafSystem):
    """Input  `state_estimate` STATE_ESTIMATE of the bank, in its active frame E
    Output `state_estimate` STATE_ESTIMATE in the anchor frame A: continuous across switches,
                             frame_id of A, frame_counter 0, X_OldNew identity
    Sampled at `period` (the bank's); a switch newer than the last sample is applied at once.
    """

    def __init__(self, period: float):
        super().__init__()
        self._estimate = self.DeclareVectorInputPort("state_estimate", STATE_ESTIMATE.size)
        initial = np.zeros(9)
        initial[_Q] = [1.0, 0.0, 0.0, 0.0]
        self._xd = self.DeclareDiscreteState(initial)
        self._frame_id = self.DeclareDiscreteState(1)
        self.DeclarePeriodicDiscreteUpdateEvent(period, 0.0, self._update)
        self.DeclareVectorOutputPort("state_estimate", STATE_ESTIMATE.size, self._calc)

    def _current(self, context, estimate) -> tuple[np.ndarray, np.ndarray, bool]:
        x = context.get_discrete_state(self._xd).get_value()
        p_AE, q_AE = x[_P], x[_Q]
        counter = STATE_ESTIMATE.get(estimate, "frame_counter")
        if x[_ANCHORED] > 0.5 and counter != x[_COUNTER]:
            p_AE, q_AE = compose(p_AE, q_AE, STATE_ESTIMATE.get(estimate, "p_OldNew"),
                                 STATE_ESTIMATE.get(estimate, "q_OldNew"))
        anchored = x[_ANCHORED] > 0.5 or STATE_ESTIMATE.get(estimate, "valid") > 0.5
        return p_AE, q_AE / np.linalg.norm(q_AE), anchored

    def _update(self, context, discrete_state):
        estimate = self._estimate.Eval(context)
        x = context.get_discrete_state(self._xd).get_value()
        p_AE, q_AE, anchored = self._current(context, estimate)
        if anchored and x[_ANCHORED] < 0.5:
            discrete_state.set_value(self._frame_id, [STATE_ESTIMATE.get(estimate, "frame_id")])
        discrete_state.set_value(self._xd, np.concatenate([
            [STATE_ESTIMATE.get(estimate, "frame_counter"), float(anchored)], p_AE, q_AE]))

    def _calc(self, context, output):
        estimate = self._estimate.Eval(context)
        p_AE, q_AE, anchored = self._current(context, estimate)
        out = reexpress(estimate, p_AE, q_AE)
        frame_id = context.get_discrete_state(self._frame_id).get_value()[0] if \
            context.get_discrete_state(self._xd).get_value()[_ANCHORED] > 0.5 else \
            STATE_ESTIMATE.get(estimate, "frame_id")
        out[STATE_ESTIMATE.slice("frame_id")] = frame_id
        out[STATE_ESTIMATE.slice("frame_counter")] = 0.0
        out[STATE_ESTIMATE.slice("p_OldNew")] = 0.0
        out[STATE_ESTIMATE.slice("q_OldNew")] = [1.0, 0.0, 0.0, 0.0]
        output.SetFromVector(out)


class FrameSwitch(LeafSystem):
    """Input  `state_estimate` STATE_ESTIMATE in frame E0
    Output `state_estimate` the same estimate in frame E1 from `at` [s] on, where X_E0E1 =
           (p_OldNew, q_OldNew): frame_id + 1, frame_counter + 1 and X_OldNew reported, as the
           arbiter does when it switches hypotheses (M Sec. 3.5)
    Stateless (a function of time): for testing that trackers, controllers and managers
    re-express their states and the vehicle does not move.
    """

    def __init__(self, at: float, p_OldNew, q_OldNew):
        super().__init__()
        self._at = float(at)
        self._p, self._q = np.asarray(p_OldNew, float), np.asarray(q_OldNew, float)
        R_OldNew = rotation_matrix(self._q)
        # X_NewOld, the inverse: what re-expresses an estimate in E0 into E1.
        self._p_NewOld = -R_OldNew.T @ self._p
        self._q_NewOld = self._q * [1.0, -1.0, -1.0, -1.0] / np.linalg.norm(self._q)
        self._estimate = self.DeclareVectorInputPort("state_estimate", STATE_ESTIMATE.size)
        self.DeclareVectorOutputPort("state_estimate", STATE_ESTIMATE.size, self._calc)

    def _calc(self, context, output):
        estimate = self._estimate.Eval(context)
        if context.get_time() < self._at:
            return output.SetFromVector(estimate)
        out = reexpress(estimate, self._p_NewOld, self._q_NewOld)
        L = STATE_ESTIMATE
        out[L.slice("frame_id")] = L.get(estimate, "frame_id") + 1.0
        out[L.slice("frame_counter")] = L.get(estimate, "frame_counter") + 1.0
        out[L.slice("p_OldNew")] = self._p
        out[L.slice("q_OldNew")] = self._q
        output.SetFromVector(out)
