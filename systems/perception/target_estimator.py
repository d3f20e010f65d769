"""The target estimator: down-camera frames -> detection / keypoint tracking -> target EKF, L Sec. 5.2
(detector.py, keypoint_tracker.py, target_ekf.py).

Each new frame is placed in time by its stamp: the camera pose T_WD of L(9) is the state estimate
interpolated at the stamp (a short history of `state_estimate` samples is kept) times the camera
extrinsics X_BC of the frame's calibration. When the odometry corrects its own position (the
VIO's keyframes; STATE_ESTIMATE `p_EO`), the target and the kept poses move by the same amount:
the keypoints measure the car relative to the vehicle (before, at 8 m/s, each 5-20 cm correction
read as target motion, 0.5-1.2 m/s of velocity error reported as 0.1, and re-initialized the
filter 2-8 times per descent). With an initialized filter that knows the target's
velocity (`track_velocity_std`; until then the detector runs first, the tracker only where it
finds nothing) the keypoints are tracked from the predicted pose and fused one by one (not those
predicted closer to the camera than `min_keypoint_depth`, where the projection's linearization
fails: after touchdown the camera sits 14 cm above the pattern and sees its centre keypoint
alone, and that bearing, fused frame after frame, dragged the estimate along its ray far beyond
the covariance); when fewer than `min_tracked_keypoints` are accepted, the detector runs and
its corners are fused the same way, or, with no accepted keypoint for `reinit_after`, or when
the filter rejects most keypoints of the detection (a track kept alive by wrong associations),
the filter is re-initialized from the detection (L Sec. 5.2.2: initialization from a full
detection; a re-initialization keeps the velocity the filter knew, `reinit_*`).
Frames of the `geometric` source carry keypoint candidates instead of an image
(down_camera.GeometricDownCamera, a sensor model of the front end): unlabelled, with false ones and
outliers; their detection is a search for the pattern's white square among them (convex quads of
candidates with the detector's minimum area that hold enough other candidates), its pose by the
detector's symmetric PnP (`PatternDetector.pose`, the 90-degree rotation nearest the filter's or the
image's up) and a verification that the pattern's other keypoints reproject onto candidates; their
tracking is the association of each predicted keypoint with the nearest candidate in the keypoint
tracker's search window. The EKF, its chi-square gating (the outlier rejection), the symmetric pose
and the re-initialization logic are the same code for both sources. (`mode: labelled` frames carry
the keypoints' ids: an idealization that skips association, kept as an option.)
Between frames the estimate is predicted to the output time, so its covariance grows while no
measurement arrives.
"""
import dataclasses as dc
import itertools

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.math import RigidTransform
from pydrake.common.eigen_geometry import Quaternion
from pydrake.systems.framework import LeafSystem

from alight.systems.boundary import STATE_ESTIMATE, TARGET_ESTIMATE, CameraFrame, VectorLayout
from alight.systems.params import bounded, param_file
from alight.systems.perception.detector import (DetectorParams, PatternDetector, Prediction,
                                                RectifiedFrame, Rectifier)
from alight.systems.perception.keypoint_tracker import KeypointTracker, KeypointTrackerParams
from alight.systems.perception.pattern import CORNER_IDS, Pattern, PatternParams
from alight.systems.perception.target_ekf import TargetEkf, TargetEkfParams
from alight.systems.rotations import all_finite, conjugate, quaternion_product, rotation_matrix
from alight.systems.sensors.down_camera_lens import Lens
from alight.systems.timing import ComputeTimer


@dc.dataclass
class TargetEstimatorParams:
    period: float = bounded(0.01, 0.001, 1.0, "s")
    pose_history: float = bounded(1.0, 0.05, 60.0, "s")
    max_pose_extrapolation: float = bounded(0.1, 0.0, 1.0, "s")
    min_tracked_keypoints: int = bounded(4, 0, 100)
    # keypoints predicted closer to the camera (depth along its axis) are not fused: the bearing's
    # 1/depth linearization fails there. A lone keypoint fused at 20 Hz for 3 s, 20 seeds: 14 cm
    # deep (the landed vehicle's camera over the pattern's centre) 37 % of the frames within 3 std,
    # 0.5 m 99 %, 1 m and 4 m 100 % (tests/test_perception_ekf.py has the 14 cm case)
    min_keypoint_depth: float = bounded(0.5, 0.0, 10.0, "m")
    reinit_after: float = bounded(0.5, 0.0, 60.0, "s")
    # keypoints are tracked from the filter's prediction first once it knows the target's
    # horizontal velocity within this; until then the detector runs first, the tracker only
    # when it finds nothing (a filter just initialized at zero velocity, 5 m/s std, over a car
    # at 6 m/s from Follow's 4.2 m: the pattern moves 37 px between frames, the nearest
    # candidates within the tracker's 30 px reach were other keypoints, and the wrong ones
    # accepted re-initialized the filter at zero velocity frame after frame)
    track_velocity_std: float = bounded(1.0, 0.0, 100.0, "m/s")
    # a re-initialization of a valid filter whose horizontal velocity std is under this keeps
    # its velocity (and acceleration), with the velocity std `reinit_velocity_std` or its own if
    # larger (beyond the paper's zero velocity: the car did not stop when the track was lost);
    # 0: always zero. At least `reinit_velocity_std`, so that a kept velocity is kept again: with
    # 0.3 a second re-initialization soon after the first zeroed the velocity of a car at 8 m/s
    # (8 of 20 runs of the 8 m/s campaign; docs/landing.md "Fast cars")
    reinit_keep_velocity_std: float = bounded(1.0, 0.0, 100.0, "m/s")
    reinit_velocity_std: float = bounded(0.5, 0.0, 100.0, "m/s")
    lost_timeout: float = bounded(2.0, 0.0, 600.0, "s")
    # search the whole frame at the coarsest pyramid level that resolves the pattern from the
    # camera's height above the ground (PatternDetector.whole_frame_level); off: full resolution
    height_level_search: bool = True
    # unlabelled keypoint candidates (the geometric camera): detection's verification
    candidate_match_radius: float = bounded(3.0, 0.1, 100.0, "px")
    candidate_min_verified: int = bounded(4, 0, 5)
    detector: DetectorParams = dc.field(default_factory=DetectorParams)
    tracker: KeypointTrackerParams = dc.field(default_factory=KeypointTrackerParams)
    ekf: TargetEkfParams = dc.field(default_factory=TargetEkfParams)
    # the landing pattern the estimator looks for (its `Pattern`), as printed on the platform
    pattern: PatternParams = param_file(PatternParams, "target_pattern.yaml")


# `perception_status`: frames processed, frames skipped (no camera pose at their stamp), detections,
# (re-)initializations, keypoints accepted and rejected (chi-square) in the last frame, detection
# used in the last frame (0/1). (The processing time of each frame goes to the estimator's
# `compute_timer`, alight.systems.timing.)
PERCEPTION_STATUS = VectorLayout("perception_status", [
    ("frames", 1), ("skipped", 1), ("detections", 1), ("initializations", 1), ("accepted", 1),
    ("rejected", 1), ("detected", 1)])


# the state estimate's fields recorded at every tick
_STAMP, _FRAME_COUNTER, _VALID = (STATE_ESTIMATE.slice(field).start for field in (
    "stamp", "frame_counter", "valid"))
_P_EB, _Q_EB, _V_EB, _P_EO = (STATE_ESTIMATE.slice(field) for field in (
    "p_EB", "q_EB", "v_EB", "p_EO"))


class PoseHistory:
    """Recent state-estimate poses of B, interpolated at camera stamps: `samples` rows
    (t, p (3), q (4), v (3)), a new array at every change (copies may share it)."""
    P, Q, V = slice(1, 4), slice(4, 8), slice(8, 11)

    def __init__(self, length: float):
        self.length = length
        self.samples = np.zeros((0, 11))

    def add(self, t: float, p, q, v) -> None:
        samples = self.samples
        if len(samples) and t <= samples[-1, 0]:
            return
        # the samples kept, newer than t - length, are the last ones (the times increase)
        kept = samples[int(np.searchsorted(samples[:, 0], t - self.length, side="right")):]
        added = np.empty((len(kept) + 1, samples.shape[1]))
        added[:-1] = kept
        added[-1, 0], added[-1, self.P], added[-1, self.Q], added[-1, self.V] = t, p, q, v
        self.samples = added

    def clear(self) -> None:
        self.__init__(self.length)

    def shift(self, dp: np.ndarray) -> None:
        """Moves every pose by dp [m] (a new array: copies may share the old one)."""
        samples = self.samples.copy()
        samples[:, self.P] += dp
        self.samples = samples

    def at(self, t: float, max_extrapolation: float) -> RigidTransform | None:
        samples, P, Q = self.samples, self.P, self.Q
        times = samples[:, 0]
        if not len(times) or t < times[0] or t > times[-1] + max_extrapolation:
            return None
        if t >= times[-1]:
            p = samples[-1, P] + samples[-1, self.V] * (t - times[-1])
            q = samples[-1, Q]
        else:
            i = int(np.searchsorted(times, t, side="right")) - 1
            a = (t - times[i]) / (times[i + 1] - times[i])
            before, after = samples[i], samples[i + 1]
            p = (1 - a) * before[P] + a * after[P]
            q1 = after[Q] if before[Q] @ after[Q] >= 0 else -after[Q]
            q = (1 - a) * before[Q] + a * q1
        return RigidTransform(Quaternion(q / np.linalg.norm(q)), p)


@dc.dataclass
class EstimatorState:
    ekf: TargetEkf
    poses: PoseHistory
    valid: bool = False
    last_frame: float = float("nan")
    last_accepted: float = float("nan")
    frame_counter: float = 0.0
    p_EO: np.ndarray = dc.field(default_factory=lambda: np.full(3, np.nan))  # the last seen
    # the last frame's fused measurements (keypoint id, rectified pixel, accepted), for analysis
    fused: tuple = ()
    status: np.ndarray = dc.field(default_factory=lambda: np.zeros(PERCEPTION_STATUS.size))

    def __deepcopy__(self, memo) -> "EstimatorState":
        """Drake's clones of the abstract state (copy.deepcopy, two per update: the copy that the
        update changes, and back): the filter and the pose history assign new arrays, never write
        into theirs, so shallow copies of them may share the arrays (and the parameters); the
        status, written in place, is copied."""
        copied = _shallow_copy(self)
        copied.ekf, copied.poses = _shallow_copy(self.ekf), _shallow_copy(self.poses)
        copied.status = self.status.copy()
        return copied


def _shallow_copy(obj):
    """copy.copy of a plain object (a new one sharing its attributes), without the copy module's
    protocol lookups."""
    copied = object.__new__(type(obj))
    copied.__dict__.update(obj.__dict__)
    return copied


class TargetEstimator(LeafSystem):
    """Input  `down_image`        CameraFrame (image, or keypoints of the geometric source)
    Input  `state_estimate`    STATE_ESTIMATE (the vehicle's pose in frame E)
    Output `target_estimate`   TARGET_ESTIMATE, predicted to the output time
    Output `perception_status` PERCEPTION_STATUS
    `compute_timer` records the wall-clock processing time of every frame.
    """

    def __init__(self, pattern: Pattern, params: TargetEstimatorParams):
        super().__init__()
        self.compute_timer = ComputeTimer()
        self._params = params
        self._pattern = pattern
        self._rectifier = Rectifier(params.detector)
        self._detector = PatternDetector(pattern, params.detector)
        self._tracker = None  # built at the first image (drawing its template takes ~0.3 s)
        self._frame = self.DeclareAbstractInputPort("down_image", AbstractValue.Make(CameraFrame()))
        self._estimate = self.DeclareVectorInputPort("state_estimate", STATE_ESTIMATE.size)
        self._state = self.DeclareAbstractState(AbstractValue.Make(EstimatorState(
            TargetEkf(params.ekf), PoseHistory(params.pose_history))))
        self.DeclarePeriodicUnrestrictedUpdateEvent(params.period, 0.0, self._update)
        self.DeclareVectorOutputPort("target_estimate", TARGET_ESTIMATE.size, self._calc_estimate,
                                     {self.abstract_state_ticket(self._state), self.time_ticket()})
        self.DeclareVectorOutputPort("perception_status", PERCEPTION_STATUS.size,
                                     self._calc_status,
                                     {self.abstract_state_ticket(self._state)})

    # --- events ---------------------------------------------------------------------------------
    def _update(self, context, state):
        # Drake hands the update a copy of the state (EstimatorState.__deepcopy__): change it there
        st = state.get_mutable_abstract_state(self._state).get_value()
        estimate = self._estimate.Eval(context)
        if estimate[_VALID] > 0.5:
            self._record_pose(st, estimate)
        frame = self._frame.Eval(context)
        if frame.valid and frame.calibration is not None and not frame.stamp <= st.last_frame:
            if frame.image is not None:
                self._keypoint_tracker()  # built before the first image's timing
            with self.compute_timer.measure(context.get_time()):
                self.process(st, frame)

    def _record_pose(self, st: EstimatorState, estimate: np.ndarray) -> None:
        # (the fields by index and the arrays' own methods: this runs at every tick)
        counter = estimate[_FRAME_COUNTER]
        p_EO = estimate[_P_EO]
        if counter != st.frame_counter:   # (the new frame's p_EO is taken as it is)
            _reexpress(st.ekf, STATE_ESTIMATE.get(estimate, "p_OldNew"),
                       STATE_ESTIMATE.get(estimate, "q_OldNew"))
            st.poses.clear()
            st.frame_counter = counter
        elif all_finite(st.p_EO) and p_EO.tolist() != st.p_EO.tolist():   # (as the arrays' !=)
            _shift(st, p_EO - st.p_EO)
        st.p_EO = p_EO.copy()
        st.poses.add(estimate[_STAMP], estimate[_P_EB], estimate[_Q_EB], estimate[_V_EB])

    def process(self, st: EstimatorState, frame: CameraFrame) -> None:
        """One frame: tracking and/or detection, EKF updates (public for tests and benchmarks)."""
        p = self._params
        status = st.status
        st.last_frame = frame.stamp
        X_WB = st.poses.at(frame.stamp, p.max_pose_extrapolation)
        if X_WB is None:
            status[PERCEPTION_STATUS.slice("skipped")] += 1
            return
        status[PERCEPTION_STATUS.slice("frames")] += 1
        lens = Lens.from_calibration(frame.calibration)
        X_WC = X_WB @ RigidTransform(lens.X_BC)
        K = lens.K_rectified
        images = self._images(frame, lens)
        ekf = st.ekf
        accepted = rejected = 0
        st.fused = ()
        guided = False   # tracked from the prediction first
        if st.valid:
            ekf.predict(frame.stamp)
            guided = self._trackable(ekf)
            if guided:
                accepted, rejected = self._track_and_fuse(st, frame, images, lens, X_WC, K)
        detected = 0
        if accepted < p.min_tracked_keypoints:
            reference = (X_WC.inverse() @ _X_WT(ekf)).rotation().matrix() \
                if ekf.initialized else None
            z_up_C = X_WC.rotation().inverse().multiply(np.array([0.0, 0.0, 1.0]))
            detection = self._detect(frame, images, lens, reference, z_up_C,
                                     _prediction(ekf, X_WC, frame.stamp),
                                     height=X_WC.translation()[2]
                                     if p.height_level_search else None)
            if detection is not None:
                status[PERCEPTION_STATUS.slice("detections")] += 1
                detected = 1
                stale = not (frame.stamp - st.last_accepted <= p.reinit_after)
                initialize = not st.valid or (accepted == 0 and stale)
                if not initialize:
                    a, r = self._fuse(st, detection[1], X_WC, K)
                    accepted, rejected = accepted + a, rejected + r
                    # the filter rejects most keypoints of a verified detection: the track was
                    # lost (kept alive by wrong associations: one wrongly associated keypoint
                    # accepted frame after frame while the detection's other eight were
                    # rejected, d^2 20-90, let a 5 m/s landing drift 0.7 m off the car in its
                    # last second), start again from the detection
                    initialize = a < r
                if initialize:
                    X_WT = X_WC @ detection[0]
                    ekf.initialize(frame.stamp, X_WT.translation(),
                                   X_WT.rotation().ToQuaternion().wxyz(),
                                   float(np.linalg.norm(detection[0].translation())),
                                   self._kept_motion(st))
                    st.valid = True
                    status[PERCEPTION_STATUS.slice("initializations")] += 1
                    accepted += len(detection[1])
            elif st.valid and not guided:
                # nothing detected (the pattern entering the view, partly out of it): track from
                # the uncertain prediction after all, the chi-square gate its only guard
                a, r = self._track_and_fuse(st, frame, images, lens, X_WC, K)
                accepted, rejected = accepted + a, rejected + r
        if accepted > 0:
            st.last_accepted = frame.stamp
        if st.valid and not frame.stamp - st.last_accepted <= p.lost_timeout:
            st.valid = False
        status[PERCEPTION_STATUS.slice("accepted")] = accepted
        status[PERCEPTION_STATUS.slice("rejected")] = rejected
        status[PERCEPTION_STATUS.slice("detected")] = detected

    def _track_and_fuse(self, st, frame, images, lens, X_WC, K) -> tuple[int, int]:
        measurements = self._track(frame, images, lens, X_WC.inverse() @ _X_WT(st.ekf))
        return self._fuse(st, measurements, X_WC, K)

    def _trackable(self, ekf: TargetEkf) -> bool:
        """The filter knows the target's horizontal velocity within `track_velocity_std`: its
        prediction can guide the tracker's search windows."""
        return ekf.horizontal_velocity_std <= self._params.track_velocity_std

    def _kept_motion(self, st: EstimatorState) -> tuple[np.ndarray, np.ndarray, float] | None:
        """The motion a re-initialization keeps (v, a, velocity std: `reinit_velocity_std`, or
        the filter's own if larger; `reinit_keep_velocity_std`), or None: zero velocity (L Sec.
        5.2.2; the first initialization, a filter no longer valid or one whose velocity is not
        known)."""
        p, ekf = self._params, st.ekf
        if not st.valid or not ekf.initialized:
            return None
        std = ekf.horizontal_velocity_std
        if std > p.reinit_keep_velocity_std:
            return None
        return ekf.v, ekf.a, max(p.reinit_velocity_std, std)

    def front_end(self, frame: CameraFrame, X_CT_predicted: RigidTransform | None = None,
                  R_CT_reference=None, z_up_C=None):
        """What the front end makes of one frame, without the filter (for the calibration bench
        and tests): (the detection (X_CT, [(keypoint id, rectified pixel)]) or None, the keypoints
        tracked from `X_CT_predicted` [(id, rectified pixel)], empty without a prediction)."""
        lens = Lens.from_calibration(frame.calibration)
        images = self._images(frame, lens)
        tracked = [] if X_CT_predicted is None else \
            self._track(frame, images, lens, X_CT_predicted)
        return self._detect(frame, images, lens, R_CT_reference, z_up_C), tracked

    # --- steps ----------------------------------------------------------------------------------
    def _keypoint_tracker(self) -> KeypointTracker:
        """The keypoint tracker, built when first needed: only image frames use it (the geometric
        source's candidates are associated by position), and drawing its template takes 0.3 s."""
        if self._tracker is None:
            self._tracker = KeypointTracker(self._pattern, self._params.tracker)
        return self._tracker

    def _images(self, frame, lens):
        if frame.image is None:
            return None
        return RectifiedFrame(self._rectifier, frame.image, lens)

    def _track(self, frame, images, lens, X_CT_predicted) -> list[tuple[int, np.ndarray]]:
        if images is not None:
            return [(m.id, m.uv) for m in self._keypoint_tracker().track(images, X_CT_predicted)]
        uv = lens.rectify_points(frame.keypoints)
        if frame.keypoint_ids is not None:  # labelled (idealized)
            return list(zip((int(i) for i in frame.keypoint_ids), uv))
        return associate(uv, self._project(X_CT_predicted, lens.K_rectified),
                         self._params.tracker.search_size / 2)

    def _detect(self, frame, images, lens, R_CT_reference, z_up_C, prediction=None,
                height=None):
        """(X_CT, [(keypoint id, rectified pixel)]) of the best detection, or None. `z_up_C`:
        the state estimate's up in the camera frame (the platform is level); `height`: the
        camera's above the ground (z = 0 of the estimate's frame), which the platform's top is
        above: the whole frame is searched at the coarsest level that still resolves the
        pattern from there (`PatternDetector.whole_frame_level`)."""
        K = lens.K_rectified
        if images is not None:
            detections = self._detector.detect(images, R_CT_reference, z_up_C, prediction,
                                               height)
            return (detections[0].X_CT, list(zip(CORNER_IDS, detections[0].corners))) \
                if detections else None
        uv = lens.rectify_points(frame.keypoints)
        if frame.keypoint_ids is not None:  # labelled (idealized): the corners are known
            ids = list(frame.keypoint_ids)
            if not all(i in ids for i in CORNER_IDS):
                return None
            corners = uv[[ids.index(i) for i in CORNER_IDS]]
            X_CT = self._detector.pose(corners, K, symmetric=False, z_up_C=z_up_C)
            return None if X_CT is None else (X_CT, list(zip(CORNER_IDS, corners)))
        return self.detect_candidates(uv, K, R_CT_reference, z_up_C)

    def detect_candidates(self, uv: np.ndarray, K: np.ndarray, R_CT_reference=None,
                          z_up_C=None):
        """The pattern among unlabelled candidates (rectified pixels): (X_CT, [(keypoint id,
        pixel)] of the candidates it explains) for the best verified quad, or None. A quad is
        verified when its corners and at least `candidate_min_verified` of the other keypoints
        reproject within `candidate_match_radius` of a candidate; the best explains the most
        candidates, then with the smallest mean distance."""
        p = self._params
        best, best_score = None, None
        for quad in convex_quads(uv, p.detector.min_quad_area, p.candidate_min_verified):
            X_CT = self._detector.pose(uv[quad], K, R_CT_reference, symmetric=True,
                                       z_up_C=z_up_C)
            if X_CT is None:
                continue
            matches = associate(uv, self._project(X_CT, K), p.candidate_match_radius)
            ids = [k for k, _ in matches]
            if not all(k in ids for k in CORNER_IDS) or \
                    len(ids) - len(CORNER_IDS) < p.candidate_min_verified:
                continue
            predicted = self._project(X_CT, K)
            error = np.mean([np.linalg.norm(z - predicted[k]) for k, z in matches])
            score = (len(matches), -error)
            if best_score is None or score > best_score:
                best, best_score = (X_CT, matches), score
        return best

    def _project(self, X_CT: RigidTransform, K: np.ndarray) -> np.ndarray:
        """Rectified pixels of the pattern's keypoints (nan behind the camera)."""
        p_C = X_CT.multiply(self._pattern.p_TK.T).T
        uv = p_C[:, :2] / p_C[:, 2:3] @ K[:2, :2].T + K[:2, 2]
        uv[p_C[:, 2] <= 0.05] = np.nan
        return uv

    def _fuse(self, st: EstimatorState, measurements, X_WC: RigidTransform,
              K) -> tuple[int, int]:
        R_WC, p_WC = X_WC.rotation().matrix(), X_WC.translation()
        accepted = rejected = 0
        fused = []
        for k, uv in measurements:
            prediction = st.ekf.keypoint(self._pattern.p_TK[k], R_WC, p_WC, K)
            if prediction is None or prediction.p_CK[2] < self._params.min_keypoint_depth:
                continue
            ok, _ = st.ekf.update(prediction, uv)
            accepted += ok
            rejected += not ok
            fused.append((int(k), np.asarray(uv, float), bool(ok)))
        st.fused = st.fused + tuple(fused)
        return accepted, rejected

    # --- outputs --------------------------------------------------------------------------------
    def _calc_estimate(self, context, output):
        st = context.get_abstract_state(self._state).get_value()
        t = context.get_time()
        ekf = st.ekf
        if not ekf.initialized:
            output.SetFromVector(TARGET_ESTIMATE.pack(
                stamp=t, p_WT=0.0, q_WT=[1, 0, 0, 0], v_WT=0.0, var_p=np.inf, var_rot=np.inf,
                var_v=np.inf, last_measurement=np.nan, valid=0.0, keypoints=0.0,
                frame_counter=st.frame_counter))
            return
        p, q, v, P = ekf.predicted(t)
        variances = np.diag(P)
        output.SetFromVector(TARGET_ESTIMATE.pack(
            stamp=t, p_WT=p, q_WT=q, v_WT=v, var_p=variances[0:3], var_rot=variances[3:6],
            var_v=variances[6:9], last_measurement=st.last_accepted, valid=float(st.valid),
            keypoints=PERCEPTION_STATUS.get(st.status, "accepted"),
            frame_counter=st.frame_counter))

    def _calc_status(self, context, output):
        output.SetFromVector(context.get_abstract_state(self._state).get_value().status)


def associate(candidates: np.ndarray, predicted: np.ndarray,
              reach: float) -> list[tuple[int, np.ndarray]]:
    """Each predicted keypoint (rows of `predicted`, nan: not predicted) with the nearest
    candidate within `reach` px in u and v (the keypoint tracker's search window), if any."""
    if not len(candidates):
        return []
    offsets = candidates[None, :, :] - predicted[:, None, :]
    inside = np.all(np.abs(offsets) <= reach, axis=2)
    distances = np.where(inside, np.linalg.norm(offsets, axis=2), np.inf)
    nearest = np.argmin(distances, axis=1)
    return [(k, candidates[j]) for k, j in enumerate(nearest) if np.isfinite(distances[k, j])]


_NEXT = [1, 2, 3, 0]   # each corner's successor around a quad (np.roll by -1, cheaper)


def convex_quads(uv: np.ndarray, min_area: float, min_inside: int) -> np.ndarray:
    """(M, 4) indices of the candidates' convex quadrilaterals of at least `min_area` px^2 that
    hold at least `min_inside` other candidates, each ordered like the detector's quads
    (keypoints 0-3 up to a cyclic shift), largest first."""
    n = len(uv)
    if n < 4:
        return np.zeros((0, 4), int)
    quads = np.array(list(itertools.combinations(range(n), 4)))
    corners = uv[quads]
    centre = corners.mean(axis=1, keepdims=True)
    angle = np.arctan2(corners[..., 1] - centre[..., 1], corners[..., 0] - centre[..., 0])
    order = np.argsort(angle, axis=1)
    quads = np.take_along_axis(quads, order, axis=1)
    corners = uv[quads]
    edges = corners[:, _NEXT] - corners
    turns = _cross(edges, edges[:, _NEXT])
    # angles increase with v down: clockwise on screen, positive turns and shoelace area
    area = 0.5 * _cross(corners, corners[:, _NEXT]).sum(axis=1)
    keep = np.all(turns > 0, axis=1) & (area >= min_area)
    quads, corners, edges, area = quads[keep], corners[keep], edges[keep], area[keep]
    inside = np.all(_cross(edges[:, :, None, :], uv[None, None, :, :] - corners[:, :, None, :])
                    > 0, axis=1).sum(axis=1)
    keep = inside >= min_inside
    quads, area = quads[keep], area[keep]
    # the detector's order: negative oriented area in image coordinates (see detector._quads)
    return quads[np.argsort(-area)][:, ::-1]


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def _X_WT(ekf: TargetEkf) -> RigidTransform:
    return RigidTransform(Quaternion(ekf.q / np.linalg.norm(ekf.q)), ekf.p)


def _reexpress(ekf: TargetEkf, p_OldNew, q_OldNew) -> None:
    """The estimator frame switched (M Sec. 3.5): express the target in the new frame."""
    if not ekf.initialized:
        return
    q_NewOld = conjugate(np.asarray(q_OldNew, float))
    R = rotation_matrix(q_NewOld)
    ekf.p = R @ (ekf.p - np.asarray(p_OldNew, float))
    ekf.v = R @ ekf.v
    ekf.a = R @ ekf.a
    ekf.q = quaternion_product(q_NewOld, ekf.q)
    G = np.kron(np.eye(ekf.n // 3), R)
    ekf.P = G @ ekf.P @ G.T


def _shift(st: EstimatorState, dp: np.ndarray) -> None:
    """The odometry corrected its own position by dp (STATE_ESTIMATE `p_EO`): the target, measured
    relative to the vehicle, and the camera poses of the frames still to come move with it."""
    if st.ekf.initialized:
        st.ekf.p = st.ekf.p + dp
    st.poses.shift(dp)


def _prediction(ekf: TargetEkf, X_WC: RigidTransform, t: float) -> Prediction | None:
    """The filter's pattern pose in the camera at t and its 1-sigma position and rotation
    uncertainty (the largest of the axes'), where the detector looks first."""
    if not ekf.initialized:
        return None
    p, q, _, P = ekf.predicted(t)
    variances = np.diag(P)
    return Prediction(X_WC.inverse() @ RigidTransform(Quaternion(q / np.linalg.norm(q)), p),
                      float(np.sqrt(variances[0:3].max())), float(np.sqrt(variances[3:6].max())))
