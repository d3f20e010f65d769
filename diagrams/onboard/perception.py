"""Wires the down camera to the target estimator (detection/tracking -> target EKF, L Sec. 5.2) so that
the mission gets one `target_estimate` port."""
import dataclasses as dc

from alight.models import model_path
from alight.systems.params import load_params
from alight.systems.perception.pattern import Pattern
from alight.systems.perception.target_estimator import TargetEstimator, TargetEstimatorParams


def load_target_estimator_params(filename: str = "target_perception.yaml") -> TargetEstimatorParams:
    return load_params(TargetEstimatorParams, model_path(filename))


@dc.dataclass(frozen=True)
class TargetPerceptionPorts:
    target_estimate: object     # OutputPort, TARGET_ESTIMATE
    perception_status: object   # OutputPort, PERCEPTION_STATUS
    estimator: TargetEstimator


def add_target_perception(builder, down_image_port, state_estimate_port,
                          params: TargetEstimatorParams,
                          name: str = "target_estimator") -> TargetPerceptionPorts:
    """Adds the target estimator of `params` (looking for `params.pattern`) reading the vehicle's
    `down_image` and a `state_estimate` (STATE_ESTIMATE, e.g. `add_mocap`'s); returns its
    `target_estimate` port."""
    estimator = builder.AddNamedSystem(name, TargetEstimator(Pattern(params.pattern), params))
    builder.Connect(down_image_port, estimator.GetInputPort("down_image"))
    builder.Connect(state_estimate_port, estimator.GetInputPort("state_estimate"))
    return TargetPerceptionPorts(estimator.GetOutputPort("target_estimate"),
                                 estimator.GetOutputPort("perception_status"), estimator)
