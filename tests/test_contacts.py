"""The vehicle's contacts in the simulation-only ground truth (alight.systems.sensors.contacts):
the legs' normal forces on the ground and on the platform, every other contact, accumulated at
every sample of the contacts (4 ms); and the legs' structural limit (`max_leg_force`,
hexacopter_f550.yaml) against the landing-gear drop tests it is sized by."""
import numpy as np
import pytest

from alight.diagrams.scenario import load_scenario, vehicle_config
from drops import drop

G = 9.81
INCH = 0.0254  # m
LIMIT_DROP = 13 * INCH             # 14 CFR 27.725(a): the landing gear's limit drop
RESERVE_DROP = 1.5 * LIMIT_DROP    # 27.727(a): the reserve energy drop, withstood unbroken


@pytest.fixture(scope="module")
def config():
    return load_scenario("hover").vehicle


def weight(config) -> float:
    return 2.5 * G  # hexacopter_f550.sdf: 2.5 kg


def test_resting_on_its_legs_the_ground_carries_the_weight(config):
    t, truth = drop(config, 0.0, duration=1.0)
    assert truth["legs_ground_force"][-1] == pytest.approx(weight(config), rel=1e-3)
    assert truth["legs_platform_force"].max() == 0.0 and truth["other_contact_force"].max() == 0.0
    # In contact at every step: the contact time is the time.
    assert truth["legs_ground_time"][-1] == pytest.approx(t[-1], abs=2 * config.time_step)
    assert truth["legs_platform_time"][-1] == 0.0 and truth["other_contact_time"][-1] == 0.0
    # Four legs share it; the most loaded peaked at 7.80 N (measured) as the unloaded legs
    # settled at the start, 27 % over a quarter of the weight (damping ratio 0.5).
    assert weight(config) / 4 < truth["peak_leg_force"][-1] < 1.3 * weight(config) / 4


def test_a_level_drop_loads_the_legs_within_their_limit_up_to_the_reserve_energy_drop(config):
    """The limit is sized by the rotorcraft landing-gear drop tests (hexacopter_f550.yaml):
    the limit drop (13 in) and the reserve energy drop (1.5 x 13 in, 3.1 m/s at contact) stay
    under it, landed on the legs; a drop from 1 m (4.4 m/s) is a hard touchdown over it."""
    limit = config.airframe.max_leg_force
    peaks = {}
    for height in (LIMIT_DROP, RESERVE_DROP, 1.0):
        t, truth = drop(config, height, duration=1.0)
        peaks[height] = truth["peak_leg_force"][-1]
        assert truth["other_contact_time"][-1] == 0.0  # on its legs, nothing else touched
        assert truth["legs_ground_force"][-1] == pytest.approx(weight(config), rel=1e-3)
        # The contact time counts the time in contact, bounces excluded (logged every step).
        in_contact = np.count_nonzero(truth["legs_ground_force"] > 0.0) * config.time_step
        assert truth["legs_ground_time"][-1] == pytest.approx(in_contact, abs=1e-9)
        assert truth["legs_ground_time"][-1] < t[-1] - np.sqrt(2 * height / G) + 0.002
    print({round(h, 3): round(f, 1) for h, f in peaks.items()})
    # Measured: 140 N (limit drop), 172 N (reserve drop), 231 N (1 m); within 5 % with the
    # phase of the first contact in the plant step and the contacts' 4 ms sampling (160-176 N
    # around the reserve drop).
    assert peaks[LIMIT_DROP] < peaks[RESERVE_DROP] <= limit < peaks[1.0]
    assert peaks[RESERVE_DROP] > 0.95 * limit  # the limit is that drop's load, no looser


def test_the_body_on_the_ground_is_an_other_contact(config):
    """Upside down, the body box lands first: not a leg contact."""
    t, truth = drop(config, 0.5, duration=0.8, rpy=(np.pi, 0.0, 0.0))
    assert truth["other_contact_time"][-1] > 0.0
    assert truth["other_contact_force"].max() > 0.0


def test_on_the_platform_the_legs_touch_the_platform_not_the_ground():
    scenario = load_scenario("field", overrides=["target_motion.speed: 0.0"])
    config = vehicle_config(scenario)
    height = config.target.platform_height
    x, y = config.target.initial_position
    t, truth = drop(config, 0.0, duration=1.0, p_WB=[x, y, height + 0.3])
    settled = t > 0.8
    assert truth["legs_platform_force"][settled] == pytest.approx(weight(config), rel=0.01)
    assert truth["legs_ground_time"][-1] == 0.0 and truth["other_contact_time"][-1] == 0.0
