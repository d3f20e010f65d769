"""External-vision fusion of the simulated PX4: a simple emulation of EKF2's fusion of an external
vision source (MAVLink ODOMETRY) into its local position, so that the autopilot's own position
modes and failsafes have a position to hold (DESIGN.md "Vehicle boundary", `odometry`).

Per axis of the local frame (W, z up) a constant-velocity Kalman filter driven by the IMU: each IMU
sample predicts position and velocity with the measured acceleration (R_WB f_B + g, R_WB from the
flight controller's attitude estimate), its process noise from EKF2_ACC_NOISE. Each new odometry
sample is fused where EKF2_EV_CTRL enables it (bit 0 horizontal position, 1 vertical position,
2 velocity; bit 3, yaw, is not emulated: the attitude is the flight controller's own). As EKF2:
the sample is taken as measured EKF2_EV_DELAY before its stamp and brought to the filter's time
with the estimated velocity; its noise is the reported variance floored at EKF2_EVP_NOISE /
EKF2_EVV_NOISE (EKF2_EV_NOISE_MD 0) or the parameters alone (1); an innovation beyond
EKF2_EVP_GATE / EKF2_EVV_GATE standard deviations is rejected; a sample of quality -1 (failed)
is ignored; a changed reset_counter resets the filter to the sample (the source changed frame);
the first sample initialises it. The local position is valid while position was fused within
EKF2_NOAID_TOUT (EKF2 dead-reckons that long without aiding); samples that keep failing the gate
for that long reset the filter to the source, as EKF2 does.
"""
import dataclasses as dc
import math

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import LeafSystem

from alight.systems.boundary import FC_ATTITUDE, STATE_ESTIMATE, ImuSamples, VectorLayout
from alight.systems.params import bounded
from alight.systems.rotations import rotation_matrix
from alight.systems.thrust_curve import GRAVITY

# EKF2_EV_CTRL bits.
HORIZONTAL_POSITION, VERTICAL_POSITION, VELOCITY, YAW = 1, 2, 4, 8


@dc.dataclass
class ExternalVisionParams:
    """PX4 EKF2's external-vision parameters (EKF2_ prefix dropped; SI units, EV_DELAY in s)."""
    ev_ctrl: int = bounded(15, 0, 15)                   # EKF2_EV_CTRL bit mask; 0: no fusion
    ev_delay: float = bounded(0.0, 0.0, 0.3, "s")       # EKF2_EV_DELAY (PX4: ms)
    ev_noise_md: int = bounded(0, 0, 1)                 # EKF2_EV_NOISE_MD
    evp_noise: float = bounded(0.1, 0.01, 10.0, "m")    # EKF2_EVP_NOISE
    evv_noise: float = bounded(0.1, 0.01, 10.0, "m/s")  # EKF2_EVV_NOISE
    evp_gate: float = bounded(5.0, 1.0, 10.0)           # EKF2_EVP_GATE [standard deviations]
    evv_gate: float = bounded(3.0, 1.0, 10.0)           # EKF2_EVV_GATE
    acc_noise: float = bounded(0.35, 0.01, 10.0, "m/s^2")  # EKF2_ACC_NOISE
    noaid_tout: float = bounded(5.0, 0.1, 60.0, "s")    # EKF2_NOAID_TOUT (PX4: us)
    period: float = bounded(0.01, 0.001, 0.1, "s")      # how often the filter runs


# Output `local_position` (the autopilot's vehicle_local_position, in W): stamp [s]; position and
# velocity of B; their variances; valid (position fused within EKF2_NOAID_TOUT); the number of
# resets (PX4's xy_reset_counter, also sent as ODOMETRY's reset_counter); samples rejected by the
# gates; time of the last position fusion [s] (-1 before the first).
LOCAL_POSITION = VectorLayout("local_position", [
    ("stamp", 1), ("p_WB", 3), ("v_WB", 3), ("var_p", 3), ("var_v", 3), ("valid", 1),
    ("reset_counter", 1), ("rejected", 1), ("last_fusion", 1)],
    defaults={"last_fusion": -1.0})

# Filter state: per axis [p, v] and the 2x2 covariance [Ppp, Ppv, Pvv]; bookkeeping.
_FILTER = VectorLayout("ev_filter", [
    ("p", 3), ("v", 3), ("P_pp", 3), ("P_pv", 3), ("P_vv", 3), ("imu_seq", 1), ("imu_t", 1),
    ("odometry_stamp", 1), ("frame_counter", 1), ("initialized", 1), ("reset_counter", 1),
    ("rejected", 1), ("last_fusion", 1), ("first_reject", 1)])


class ExternalVisionFusion(LeafSystem):
    """Input  `odometry`       STATE_ESTIMATE of the external vision source (W, stamped on this
                               clock); may be left unconnected (no source: never valid)
    Input  `imu`            ImuSamples
    Input  `fc_attitude`    FC_ATTITUDE (R_WB for the acceleration)
    Output `local_position` LOCAL_POSITION, updated every `period`"""

    def __init__(self, params: ExternalVisionParams):
        super().__init__()
        self._p = params
        self._odometry = self.DeclareVectorInputPort("odometry", STATE_ESTIMATE.size)
        self._imu = self.DeclareAbstractInputPort("imu", AbstractValue.Make(ImuSamples.empty()))
        self._attitude = self.DeclareVectorInputPort("fc_attitude", FC_ATTITUDE.size)
        initial = _FILTER.vector(imu_seq=-1.0, imu_t=math.nan, odometry_stamp=-math.inf,
                                 frame_counter=math.nan, last_fusion=-1.0,
                                 first_reject=math.nan)
        self._xd = self.DeclareDiscreteState(initial)
        self._out = self.DeclareDiscreteState(LOCAL_POSITION.vector())
        self.DeclarePeriodicDiscreteUpdateEvent(params.period, 0.0, self._update)
        self.DeclareStateOutputPort("local_position", self._out)

    def _update(self, context, discrete_state):
        if not self._odometry.HasValue(context) or self._p.ev_ctrl == 0:
            return  # no external vision: the local position stays invalid
        x = context.get_discrete_state(self._xd).get_value().copy()
        now = context.get_time()
        self._predict(x, self._imu.Eval(context), self._attitude.Eval(context))
        estimate = self._odometry.Eval(context)
        if STATE_ESTIMATE.get(estimate, "stamp") > _FILTER.get(x, "odometry_stamp"):
            x[_FILTER.slice("odometry_stamp")] = STATE_ESTIMATE.get(estimate, "stamp")
            self._fuse(x, estimate, now)
        discrete_state.set_value(self._xd, x)
        L, F = LOCAL_POSITION, _FILTER
        last = F.get(x, "last_fusion")
        discrete_state.set_value(self._out, L.vector(
            stamp=now, p_WB=F.get(x, "p"), v_WB=F.get(x, "v"), var_p=F.get(x, "P_pp"),
            var_v=F.get(x, "P_vv"),
            valid=float(F.get(x, "initialized") > 0.5 and now - last <= self._p.noaid_tout),
            reset_counter=F.get(x, "reset_counter"), rejected=F.get(x, "rejected"),
            last_fusion=last))

    def _predict(self, x, imu: ImuSamples, attitude):
        """Each new IMU sample: p += v dt + a dt^2/2, v += a dt; P = F P F' + Q (white
        acceleration noise of EKF2_ACC_NOISE)."""
        F = _FILTER
        new = imu.newer_than(int(F.get(x, "imu_seq")))
        if not len(new):
            return
        R_WB = rotation_matrix(FC_ATTITUDE.get(attitude, "q_WB"))
        q = self._p.acc_noise ** 2
        t_prev = F.get(x, "imu_t")
        for t, accel in zip(new.t, new.accel):
            dt = t - t_prev if math.isfinite(t_prev) else 0.0
            t_prev = t
            if not (0.0 < dt < 0.1) or F.get(x, "initialized") < 0.5:
                continue
            a = R_WB @ accel - np.array([0.0, 0.0, GRAVITY])
            x[F.slice("p")] += x[F.slice("v")] * dt + 0.5 * a * dt * dt
            x[F.slice("v")] += a * dt
            pp, pv, vv = (x[F.slice(name)].copy() for name in ("P_pp", "P_pv", "P_vv"))
            x[F.slice("P_pp")] = pp + 2 * dt * pv + dt * dt * vv + q * dt ** 4 / 4
            x[F.slice("P_pv")] = pv + dt * vv + q * dt ** 3 / 2
            x[F.slice("P_vv")] = vv + q * dt * dt
        x[F.slice("imu_seq")] = new.seq[-1]
        x[F.slice("imu_t")] = t_prev

    def _noise(self, reported, floor):
        reported = np.asarray(reported, dtype=float)
        if self._p.ev_noise_md == 1 or not np.all(np.isfinite(reported)):
            return np.full(3, floor ** 2)
        return np.maximum(reported, floor ** 2)

    def _fuse(self, x, estimate, now):
        F, S, p = _FILTER, STATE_ESTIMATE, self._p
        if S.get(estimate, "valid") < 0.5:
            return  # quality -1: failed
        var = S.get(estimate, "var_pv")
        p_meas, v_meas = S.get(estimate, "p_EB"), S.get(estimate, "v_EB")
        age = max(0.0, F.get(x, "imu_t") - (S.get(estimate, "stamp") - p.ev_delay)) \
            if math.isfinite(F.get(x, "imu_t")) else 0.0
        var_p, var_v = self._noise(var[:3], p.evp_noise), self._noise(var[3:], p.evv_noise)
        counter = S.get(estimate, "frame_counter")
        stale = now - F.get(x, "last_fusion") > p.noaid_tout
        if F.get(x, "initialized") < 0.5 or counter != F.get(x, "frame_counter") \
                or (stale and F.get(x, "initialized") > 0.5):
            v0 = v_meas if np.all(np.isfinite(v_meas)) else np.zeros(3)
            x[F.slice("p")], x[F.slice("v")] = p_meas + v0 * age, v0
            x[F.slice("P_pp")], x[F.slice("P_pv")] = var_p, 0.0
            x[F.slice("P_vv")] = var_v if np.all(np.isfinite(v_meas)) else 1.0
            x[F.slice("reset_counter")] += F.get(x, "initialized") > 0.5
            x[F.slice("initialized")] = 1.0
            x[F.slice("frame_counter")] = counter
            x[F.slice("last_fusion")] = now
            return
        fused = False
        axes = np.array([bool(p.ev_ctrl & HORIZONTAL_POSITION)] * 2
                        + [bool(p.ev_ctrl & VERTICAL_POSITION)])
        z = p_meas + x[F.slice("v")] * age  # the delayed sample brought to the filter's time
        fused |= self._update_axes(x, z, var_p, axes, 0, p.evp_gate)
        if p.ev_ctrl & VELOCITY and np.all(np.isfinite(v_meas)):
            self._update_axes(x, v_meas, var_v, np.ones(3, bool), 1, p.evv_gate)
        if fused:
            x[F.slice("last_fusion")] = now

    def _update_axes(self, x, z, r, axes, state: int, gate: float) -> bool:
        """Scalar Kalman updates of position (state 0) or velocity (1) on `axes`, each gated;
        True when any position/velocity axis was fused."""
        F = _FILTER
        pp, pv, vv = (x[F.slice(name)].copy() for name in ("P_pp", "P_pv", "P_vv"))
        value = x[F.slice("p")] if state == 0 else x[F.slice("v")]
        var = pp if state == 0 else vv
        innovation = z - value
        s = var + r
        accept = axes & (innovation ** 2 <= gate ** 2 * s)
        x[F.slice("rejected")] += int(np.sum(axes & ~accept))
        k_p = np.where(accept, (pp if state == 0 else pv) / s, 0.0)
        k_v = np.where(accept, (pv if state == 0 else vv) / s, 0.0)
        x[F.slice("p")] += k_p * innovation
        x[F.slice("v")] += k_v * innovation
        h_pp, h_pv = (pp, pv) if state == 0 else (pv, vv)  # the measured row of P
        x[F.slice("P_pp")] = pp - k_p * h_pp
        x[F.slice("P_pv")] = pv - k_p * h_pv if state == 0 else pv - k_v * h_pp
        x[F.slice("P_vv")] = vv - k_v * h_pv
        return bool(np.any(accept))
