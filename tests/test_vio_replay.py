"""bench/onboard.py's replay (issue 19): the onboard stack on a RecordedVehicle sees what it saw in
flight. The VIO depends only on the recorded streams (IMU, RGB-D frames), so its replayed estimate
must equal the flown one bit for bit, and a value that appeared at t is seen only after the other
updates at t, as in the simulation."""
import importlib.util
from pathlib import Path

import numpy as np

from alight.systems.boundary import STATE_ESTIMATE
from alight.diagrams.scenario import load_scenario

BENCH = Path(__file__).resolve().parents[1] / "bench" / "onboard.py"


def _bench():
    spec = importlib.util.spec_from_file_location("bench_onboard", BENCH)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_a_value_is_in_force_strictly_after_the_time_it_appeared():
    onboard = _bench()
    times = np.array([0.0, 0.005, 0.010])
    assert [onboard._index(times, t) for t in (0.0, 0.005, 0.0075, 0.010, 0.02)] == \
        [-1, 0, 1, 1, 2]


def test_the_replayed_vio_estimate_is_the_flown_one(tmp_path):
    onboard = _bench()
    scenario = load_scenario("field", overrides=["onboard.estimator: vio",
                                                 *onboard.SENSING["geometric"]])
    stack = onboard.record(scenario, 2.5, tmp_path)
    flown = stack.loggers.vector_sinks["vio_estimate"][0].take()
    recording = onboard.Recording(tmp_path)
    assert recording.duration == 2.5 and len(recording.times["rgbd"]) == 75
    timers, cpu, reader, replayed_stack, _ = onboard.replay(scenario, recording)
    replayed = replayed_stack.loggers.vector_sinks["vio_estimate"][0].take()
    # one estimate per IMU period (250 Hz) from t = 0 to 2.5 s (rows: time, then the estimate)
    assert flown.shape == replayed.shape == (round(2.5 / scenario.onboard.vio.period) + 1,
                                             1 + STATE_ESTIMATE.size)
    valid = flown[:, 1 + STATE_ESTIMATE.slice("valid").start] > 0.5
    assert 0.5 < valid.mean() < 1.0   # initialized from rest during the recording
    np.testing.assert_array_equal(replayed, flown)
    assert len(timers["vio"].seconds("frontend")) == 75 and cpu > 0 and reader > 0
    # the rest of every VIO tick (IMU pre-integration, the propagated estimate) is timed too:
    # one per update from t = 0 to 2.496 s (the log also holds the estimate at 2.5 s)
    assert len(timers["vio"].seconds("propagation")) == len(flown) - 1
