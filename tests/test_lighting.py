"""The rendered scene's light (issue 20, diagrams/world/lighting.py): drawn per run from the
scenario's seed, the same for the same seed, and the landing pattern is found under every drawn
light."""
import dataclasses as dc

import numpy as np
import pytest
from pydrake.math import RigidTransform, RollPitchYaw

from alight.diagrams.onboard.perception import load_target_estimator_params
from alight.diagrams.scenario import load_scenario, vehicle_config
from alight.diagrams.world.lighting import LightingParams, draw_light, render_engine_params
from alight.diagrams.world.target import DownCameraRig
from alight.systems.perception.detector import PatternDetector, RectifiedFrame, Rectifier
from alight.systems.sensors.down_camera import DownCameraParams
from alight.systems.target.vehicle import load_target_params

SEEDS = range(6)


def test_the_light_is_drawn_from_the_scenario_seed_within_its_ranges():
    params = LightingParams()
    lights = [draw_light(dc.replace(params, seed=s)) for s in range(200)]
    assert draw_light(dc.replace(params, seed=3)) == lights[3]          # reproducible
    assert len({light.sun_azimuth for light in lights}) == 200           # varies per run
    elevations = [light.sun_elevation for light in lights]
    assert params.sun_elevation[0] <= min(elevations) and max(elevations) <= \
        params.sun_elevation[1]
    irradiance = [light.ground_irradiance() for light in lights]
    assert min(irradiance) >= params.exposure[0] - 1e-9
    assert max(irradiance) <= params.exposure[1] + 1e-9
    # the sun shines down, from its azimuth
    light = lights[0]
    direction = light.direction()
    assert direction[2] == pytest.approx(-np.sin(np.radians(light.sun_elevation)))
    assert np.degrees(np.arctan2(-direction[1], -direction[0])) % 360 == \
        pytest.approx(light.sun_azimuth)
    scenario = load_scenario("field", overrides=["random_seed: 7"])
    assert vehicle_config(scenario).lighting.seed == 7
    assert len(render_engine_params(vehicle_config(scenario).lighting).lights) == 2
    assert render_engine_params(LightingParams(kind="camera")).lights == []   # Drake's headlight


@pytest.fixture(scope="module")
def frames():
    """The platform seen from 3, 6 and 10 m by the level camera, under the lights of seeds 0-5
    (a rig per light: the renderer's light is fixed when it is built)."""
    camera = DownCameraParams(width=640, height=512, focal_length=320.0)
    target = load_target_params()
    params = load_target_estimator_params().detector
    out = []
    for seed in SEEDS:
        rig = DownCameraRig(camera, target, LightingParams(seed=seed))
        detector = PatternDetector(rig.scene.pattern, params)
        rectifier = Rectifier(params)
        for height in (3.0, 6.0, 10.0):
            X_WC = RigidTransform(RollPitchYaw(np.pi, 0.0, 0.3), [
                2.0, -1.0, target.platform_height + height])
            X_WB = X_WC @ rig.X_BC.inverse()
            image = rig.render(X_WB, (2.0, -1.0, 0.4), seed=seed)
            frame = RectifiedFrame(rectifier, image, rig.lens)
            found = detector.detect(frame, z_up_C=X_WC.rotation().inverse().multiply(
                np.array([0.0, 0.0, 1.0])))
            out.append(dict(seed=seed, height=height, image=image, X_CT=rig.X_CT(),
                            detections=found))
    return out


def test_the_pattern_is_found_to_centimetres_under_every_drawn_light(frames):
    for f in frames:
        assert f["detections"], f"seed {f['seed']}, {f['height']} m: pattern not found"
        error = np.linalg.norm(f["detections"][0].X_CT.translation() -
                               f["X_CT"].translation())
        assert error < 0.01 * f["height"] + 0.02, (f["seed"], f["height"], error)


def test_the_drawn_lights_change_the_images(frames):
    """The mean grey level of the same view differs between lights by more than the image noise
    (the exposure range is 0.8-1.1 of the headlight scene's)."""
    means = [f["image"].mean() for f in frames if f["height"] == 6.0]
    assert np.ptp(means) > 5.0, means
