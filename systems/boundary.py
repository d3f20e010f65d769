"""The vehicle boundary of DESIGN.md: port names, vector layouts and value types.

Both the simulated hexacopter and the MAVLink vehicle export exactly these ports. Vector ports are
described by a `VectorLayout` (named fields, used for packing, slicing and log column names).
"""
import dataclasses as dc
import enum

import numpy as np


class VectorLayout:
    """Named fields of a flat vector: `layout.slice("q_WB")`, `layout.names()` for log columns.

    `defaults` are the values of fields left out: `vector` gives every field not named its default
    (zero where the layout declares none); `pack` may leave out only the fields with a declared one.
    """

    def __init__(self, name: str, fields: list[tuple[str, int]], defaults: dict | None = None):
        self.name = name
        self.fields = list(fields)
        self.defaults = dict(defaults or {})
        self._slices = {}
        start = 0
        for field, size in self.fields:
            self._slices[field] = slice(start, start + size)
            start += size
        self.size = start
        # get(): the index of a one-element field (a scalar), the slice of the others.
        self._items = {field: self._slices[field].start if size == 1 else self._slices[field]
                       for field, size in self.fields}
        self._required = frozenset(f for f, _ in self.fields) - set(self.defaults)
        self._default = np.zeros(self.size)
        for field, value in self.defaults.items():
            self._default[self._slices[field]] = value

    def slice(self, field: str) -> slice:
        return self._slices[field]

    def get(self, vector, field: str):
        vector = np.asarray(vector)
        if vector.ndim == 1:
            return vector[self._items[field]]
        value = vector[self._slices[field]]
        return value[0] if value.size == 1 else value

    def vector(self, **values) -> np.ndarray:
        """A vector from the named fields, every other field at its default (zero if undeclared):
        `STATE_ESTIMATE.vector(p_EB=[1, 2, 3])`."""
        vector = self._default.copy()
        slices = self._slices
        for field, value in values.items():
            vector[slices[field]] = value
        return vector

    def pack(self, **values) -> np.ndarray:
        """`vector`, for producers: leaving out a field without a declared default is an error."""
        if not self._required.issubset(values):
            missing = self._required - set(values)
            raise ValueError(f"{self.name}: missing fields {sorted(missing)}")
        return self.vector(**values)

    def names(self) -> list[str]:
        """One column name per element: `field` for scalars, `field_0`, `field_1`... otherwise."""
        names = []
        for field, size in self.fields:
            names += [field] if size == 1 else [f"{field}_{i}" for i in range(size)]
        return names


class CommandMode(enum.IntEnum):
    """`fc_command` modes: what the landing paper sends, and what the flight-stack paper sends."""
    ATTITUDE_THRUST = 1
    RATES_THRUST = 2


class ActiveMode(enum.IntEnum):
    """What the flight controller is doing, reported on `fc_status`."""
    DISARMED = 0
    ATTITUDE_THRUST = 1
    RATES_THRUST = 2
    FAILSAFE_DESCENT = 3


class Refusal(enum.IntEnum):
    """Why the flight controller refused a command (last one on `fc_status`)."""
    NONE = 0
    NOT_FINITE = 1
    BAD_MODE = 2
    THRUST_RANGE = 3
    QUATERNION_NORM = 4
    BODY_RATE_RANGE = 5
    ARM_FLAG = 6
    STAMP_ORDER = 7


# Input `fc_command`: stamp [s, sender clock]; mode (CommandMode); q_WD reference orientation
# (w, x, y, z) of the desired body frame D in W; w_D reference body rates [rad/s, in B];
# collective thrust in [0, 1] (thrust curve M(32)-(34)); arm request (0 or 1).
FC_COMMAND = VectorLayout("fc_command", [
    ("stamp", 1), ("mode", 1), ("q_WD", 4), ("w_D", 3), ("thrust", 1), ("arm", 1)])

# Output `fc_attitude`: stamp [s]; q_WB estimated orientation (w, x, y, z); w_B body rates [rad/s].
FC_ATTITUDE = VectorLayout("fc_attitude", [("stamp", 1), ("q_WB", 4), ("w_B", 3)])

# Output `fc_status`: stamp [s]; armed; active mode (ActiveMode); link alive (a valid command newer
# than the stale timeout); stamp of the last accepted command [s] (NO_COMMAND_STAMP before the
# first: every value on a port is finite); refused command count; last refusal (Refusal); landed
# (the land detector's verdict).
FC_STATUS = VectorLayout("fc_status", [
    ("stamp", 1), ("armed", 1), ("mode", 1), ("link_alive", 1), ("last_command_stamp", 1),
    ("refused", 1), ("last_refusal", 1), ("landed", 1)])
NO_COMMAND_STAMP = -1.0  # s: stamps are times of the simulation or the onboard clock, from 0

# Output `range` (the downward rangefinder, M Sec. 3.1.2; on PX4 DISTANCE_SENSOR): stamp of the
# measurement [s]; range: distance along -b3 to the first surface below (ground, car, platform)
# [m]; var [m^2]; valid (0: none yet, out of range, too tilted, or no rangefinder fitted).
RANGE = VectorLayout("range", [("stamp", 1), ("range", 1), ("var", 1), ("valid", 1)])

# The vehicle's contacts (simulation only; alight.systems.sensors.contacts, DESIGN.md "Landing is
# judged physically"), sampled every few plant steps: summed normal forces [N] of its legs on the
# landing platform, of its legs on the ground, and of every other contact of the vehicle (its body
# on anything, a leg on the car's body); the time spent in each kind of contact since the start [s]
# (non-decreasing: a contact between two logged samples shows as an increase); the largest normal
# force on one leg at any sample so far [N] (non-decreasing).
CONTACTS = VectorLayout("contacts", [
    ("legs_platform_force", 1), ("legs_ground_force", 1), ("other_contact_force", 1),
    ("legs_platform_time", 1), ("legs_ground_time", 1), ("other_contact_time", 1),
    ("peak_leg_force", 1)])

# Output `ground_truth` (simulation only, never read onboard): p_WB [m]; q_WB (w, x, y, z);
# v_WB [m/s, in W]; w_WB_B body rates [rad/s, in B]; wind velocity v_WA [m/s, in W];
# the flight controller's ESC commands in [0, 1]; rotor thrusts [N]. The moving target (issue 5):
# p_WT, q_WT, v_WT of the target frame T (the landing pattern's centre on the platform top, z up)
# and target_present (1 when the scene has a target; else the target fields are zero/identity).
# Then the vehicle's CONTACTS.
GROUND_TRUTH = VectorLayout("ground_truth", [
    ("p_WB", 3), ("q_WB", 4), ("v_WB", 3), ("w_WB_B", 3), ("v_WA", 3), ("motor_command", 6),
    ("rotor_thrust", 6), ("p_WT", 3), ("q_WT", 4), ("v_WT", 3), ("target_present", 1),
    *CONTACTS.fields],
    defaults={"p_WT": 0.0, "q_WT": [1.0, 0.0, 0.0, 0.0], "v_WT": 0.0, "target_present": 0.0,
              **{field: 0.0 for field, _ in CONTACTS.fields}})


class _ImuStore:
    """Arrays that successive `ImuSamples.appended` buffers view: each new sample goes into the
    next free row (`end`), so appending copies one sample, not the buffer. Rows below `end` are
    never written again; when the rows run out, the kept samples move to a new store (the old
    one stays as the buffers viewing it saw it). The buffers view `readonly`, read-only views of
    the arrays written (a slice of them is read-only as made, which is faster than marking it)."""

    def __init__(self, rows: int):
        self.arrays = (np.zeros(rows, np.int64), np.zeros(rows), np.zeros((rows, 3)),
                       np.zeros((rows, 3)))                # seq, t, accel, gyro
        self.readonly = tuple(array.view() for array in self.arrays)
        for view in self.readonly:
            view.flags.writeable = False
        self.end = 0  # rows in use


@dc.dataclass(frozen=True)
class ImuSamples:
    """The `imu` port value: the most recent IMU samples, oldest first, each with its own sequence
    number and timestamp. A consumer keeps the last sequence number it used and takes
    `newer_than(seq)`: every sample is seen exactly once as long as it reads at least once per
    buffer length (`capacity / rate`). A gap in `seq` means samples were lost upstream.

    accel: specific force in B [m/s^2]; gyro: angular velocity of B in B [rad/s]. `seq` increases
    from each sample to the next (every producer numbers them so).
    """
    seq: np.ndarray    # (N,) int64
    t: np.ndarray      # (N,) s
    accel: np.ndarray  # (N, 3)
    gyro: np.ndarray   # (N, 3)
    # the _ImuStore whose rows [end - N, end) these arrays view, if `appended` made them
    _store: _ImuStore | None = dc.field(default=None, repr=False, compare=False)
    _end: int = dc.field(default=0, repr=False, compare=False)

    @staticmethod
    def empty() -> "ImuSamples":
        return ImuSamples(np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 3)), np.zeros((0, 3)))

    def newer_than(self, seq: int) -> "ImuSamples":
        first = int(self.seq.searchsorted(seq, side="right"))  # seq increases
        if first == 0:
            return self
        return ImuSamples(self.seq[first:], self.t[first:], self.accel[first:], self.gyro[first:])

    def appended(self, seq: int, t: float, accel, gyro, capacity: int) -> "ImuSamples":
        """A new buffer with one more sample, keeping at most `capacity` samples.

        One writer at a time: the sample goes into the store row after this buffer's last unless
        another buffer was appended to this one already (a cloned context stepping on), in which
        case, as when the store is full or this buffer was not made here, the kept samples move to
        a new store."""
        keep = min(len(self), capacity - 1)  # samples of this buffer in the new one
        store = self._store
        if store is None or store.end != self._end or store.end == len(store.arrays[0]):
            store = _ImuStore(2 * capacity)
            for new, old in zip(store.arrays, (self.seq, self.t, self.accel, self.gyro)):
                new[:keep] = old[len(old) - keep:]
            store.end = keep
        end = store.end
        seqs, ts, accels, gyros = store.arrays
        seqs[end], ts[end], accels[end], gyros[end] = seq, t, accel, gyro
        store.end = end = end + 1
        rows = slice(end - keep - 1, end)
        seqs, ts, accels, gyros = store.readonly
        return ImuSamples(seqs[rows], ts[rows], accels[rows], gyros[rows], store, end)

    def __len__(self) -> int:
        return len(self.seq)

    def __post_init__(self):
        for array in (self.seq, self.t, self.accel, self.gyro):
            if isinstance(array, np.ndarray) and array.flags.writeable:
                array.flags.writeable = False  # immutable, so that copies may share it

    def __deepcopy__(self, memo) -> "ImuSamples":
        """Itself: a frozen value with read-only arrays. Drake clones abstract port and state
        values (copy.deepcopy) several times per IMU sample; sharing makes that free."""
        return self

    def __reduce__(self):
        """Pickled as its arrays alone (not the store they view)."""
        return ImuSamples, (self.seq, self.t, self.accel, self.gyro)


@dc.dataclass(frozen=True)
class CameraFrame:
    """The `rgbd` and `down_image` port value: the latest frame, or `None` fields when the vehicle
    has no such camera fitted (the camera issues fill these in).

    stamp: exposure time [s]; image: HxW (grayscale) or HxWx3 colour; depth: HxW [m] or None;
    calibration: dict with K (3x3), distortion, width, height, X_BC (camera pose in B), or None.
    A `geometric` camera source (DESIGN.md "Simulation fidelity") sends no image but keypoint
    observations instead: `keypoints` (N, 2) pixel coordinates in the (distorted) image, with the
    ids of the observed pattern keypoints in `keypoint_ids` (N,), and the same calibration.

    A frame is a value: its arrays are read-only once it is made, and copies of it (Drake clones
    port and state values with copy.deepcopy, several times per frame and tick) share it.
    """
    stamp: float = float("nan")
    image: np.ndarray | None = None
    depth: np.ndarray | None = None
    calibration: dict | None = None
    keypoints: np.ndarray | None = None
    keypoint_ids: np.ndarray | None = None

    @property
    def valid(self) -> bool:
        return (self.image is not None or self.keypoints is not None) and np.isfinite(self.stamp)

    def __post_init__(self):
        for array in (self.image, self.depth, self.keypoints, self.keypoint_ids):
            if isinstance(array, np.ndarray):
                array.flags.writeable = False

    def __deepcopy__(self, memo) -> "CameraFrame":
        return self


VECTOR_OUTPUTS = {"fc_attitude": FC_ATTITUDE, "fc_status": FC_STATUS, "range": RANGE}
ABSTRACT_OUTPUTS = {"imu": ImuSamples, "rgbd": CameraFrame, "down_image": CameraFrame}
SIM_ONLY_OUTPUTS = {"ground_truth": GROUND_TRUTH}


# --- Onboard contracts (between onboard parts; not vehicle ports) -----------------------------

# `state_estimate` (DESIGN.md "The onboard stack"): stamp [s]; position, velocity, acceleration of B
# in the active estimator frame E (z up) [m, m/s, m/s^2]; q_EB orientation (w, x, y, z); heading
# M(3)-(5) and heading rate [rad, rad/s]; variances of [p, v] (6) and of the heading; the id of the
# active estimator frame and a counter that changes whenever the arbiter switches frames; the
# transform from the old to the new frame at the last switch (p_OldNew, q_OldNew); valid (0/1);
# p_EO [m], the position in E of the odometry frame O in which the estimate is continuous: the
# sum of the corrections the estimator made to its own propagated position (a VIO keyframe's
# smoother moving the current pose by 5-20 cm at 8 m/s), so that p_EB - p_EO only moves with the
# IMU. A consumer that holds a state measured relative to the vehicle (the target estimator)
# shifts it by the change of p_EO; zero from sources that do not correct a propagation (mocap).
# Defaults (`STATE_ESTIMATE.vector(p_EB=...)`): a valid estimate at rest, level and heading 0 in
# frame 0 with no switch yet: identity q_EB and q_OldNew, valid 1, every other field 0.
STATE_ESTIMATE = VectorLayout("state_estimate", [
    ("stamp", 1), ("p_EB", 3), ("v_EB", 3), ("a_EB", 3), ("q_EB", 4), ("heading", 1),
    ("heading_rate", 1), ("var_pv", 6), ("var_heading", 1), ("frame_id", 1),
    ("frame_counter", 1), ("p_OldNew", 3), ("q_OldNew", 4), ("valid", 1), ("p_EO", 3)],
    defaults={"q_EB": [1.0, 0.0, 0.0, 0.0], "q_OldNew": [1.0, 0.0, 0.0, 0.0], "valid": 1.0,
              "p_EO": [0.0, 0.0, 0.0]})
_ESTIMATE_VALID = STATE_ESTIMATE.slice("valid").start   # (read at every controller tick)


# Inputs of the vehicle boundary: `fc_command`, and `odometry`, the onboard state estimate the
# flight controller fuses as external vision (DESIGN.md "Vehicle boundary"; MAVLink ODOMETRY).
INPUTS = {"fc_command": FC_COMMAND, "odometry": STATE_ESTIMATE}


def estimate_is_valid(estimate: np.ndarray) -> bool:
    """A STATE_ESTIMATE that says it is valid and is finite (what controllers and trackers use)."""
    return estimate[_ESTIMATE_VALID] > 0.5 and bool(np.isfinite(estimate).all())


# `target_estimate` (DESIGN.md "The onboard stack"; L(5)-(10), (28)-(35)): the target EKF's estimate
# predicted to `stamp` [s]: position p_WT [m], orientation q_WT (w, x, y, z) and velocity v_WT
# [m/s] of the target frame T (landing-pattern centre, z up) in the state estimate's frame E (W of
# the paper); variances of position [m^2], orientation (tangent space, rad^2) and velocity
# [(m/s)^2]; the stamp of the last frame whose keypoints were accepted [s] (nan before the first);
# valid (1 once initialized from a full detection and not lost); the number of keypoints accepted
# in the last frame; the state estimate's frame counter the estimate is expressed in.
TARGET_ESTIMATE = VectorLayout("target_estimate", [
    ("stamp", 1), ("p_WT", 3), ("q_WT", 4), ("v_WT", 3), ("var_p", 3), ("var_rot", 3),
    ("var_v", 3), ("last_measurement", 1), ("valid", 1), ("keypoints", 1), ("frame_counter", 1)])

# `reference` chi of M(16), produced by trackers for controllers: position, velocity, acceleration,
# jerk of the desired body position in the estimator frame E [m, m/s, m/s^2, m/s^3]; heading and
# heading rate [rad, rad/s]. The landing paper's MPC reads position and velocity (L Sec. 6.3).
REFERENCE = VectorLayout("reference", [
    ("stamp", 1), ("p", 3), ("v", 3), ("a", 3), ("j", 3), ("heading", 1), ("heading_rate", 1)])

# `controller_status`, next to every controller's `fc_command` output: valid (0/1: the command is
# usable; 0 means the control manager must fall back), reason (controller-specific code, 0 = ok),
# solver status (solver-specific code, 0 = solved or n/a). Compute times are not state: they go to
# the system's `compute_timer` (alight.systems.timing) and the run folder's `timing` stream.
CONTROLLER_STATUS = VectorLayout("controller_status", [
    ("valid", 1), ("reason", 1), ("solver_status", 1)])

# The controller contract (DESIGN.md "The onboard stack"): every controller is a LeafSystem with
# inputs `state_estimate` (STATE_ESTIMATE), `reference` (REFERENCE), `active` (1: only the active one
# computes), `last_command` (FC_COMMAND: the command last issued by whichever controller was active;
# a controller that becomes active starts from it, M Sec. 7.2), and outputs `fc_command`
# (FC_COMMAND, never NaN or out of range) and `controller_status` (CONTROLLER_STATUS). Controllers
# may add outputs of their own (e.g. `desired_acceleration`, M(53)). Optional pair: a controller
# with a `disturbance_estimate` output and a `last_disturbance` input (DISTURBANCE_ESTIMATE of
# alight.systems.control.disturbance) gets, through the control manager, the previous active
# controller's disturbance and mass estimates at activation (M Sec. 7.2).
CONTROLLER_INPUTS = {"state_estimate": STATE_ESTIMATE, "reference": REFERENCE, "active": None,
                     "last_command": FC_COMMAND}
CONTROLLER_OUTPUTS = {"fc_command": FC_COMMAND, "controller_status": CONTROLLER_STATUS}

# `tracker_status`, next to every tracker's `reference` output (fields as CONTROLLER_STATUS).
TRACKER_STATUS = VectorLayout("tracker_status", CONTROLLER_STATUS.fields)

# `tracker_status.reason` of a tracker whose reference is held back by admittance (M Sec. 4.2: the
# vehicle is held on the ground, e.g. entangled at take-off). The error it leaves is the pull of
# what holds the vehicle, not a disturbance: controllers with a `tracker_status` input (the active
# tracker's, through the control manager) hold their disturbance and mass integrators M(35)-(37).
ADMITTANCE_HOLD = 7

# The tracker contract (DESIGN.md "The onboard stack", M Sec. 4 and 7.2): every tracker is a
# LeafSystem with inputs `state_estimate` (STATE_ESTIMATE), `goal` (abstract: a
# alight.systems.tracking.goal.TrackerGoal, or a tracker-specific goal), `active` (1: only the
# active one computes) and `last_reference` (REFERENCE: the reference the control manager issued
# last; a tracker that becomes active starts from it), and outputs `reference` (REFERENCE, chi of
# M(16) in E) and `tracker_status` (TRACKER_STATUS). Trackers update with periodic unrestricted
# update events: Drake applies those before the discrete updates of the control manager and the
# controllers at the same tick, which therefore read this tick's reference (at an estimator frame
# switch, one already re-expressed by the tracker in the new frame).
TRACKER_INPUTS = {"state_estimate": STATE_ESTIMATE, "goal": None, "active": None,
                  "last_reference": REFERENCE}
TRACKER_OUTPUTS = {"reference": REFERENCE, "tracker_status": TRACKER_STATUS}
