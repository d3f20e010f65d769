"""The Meshcat flight view (diagrams/world/visualization.py): the replay opens framed on the
vehicle and the car, draws their paths, labels the mission's mode. Checked in what the user gets,
the replay's HTML: its scene commands and its animation tracks, decoded (no browser here; a
headless-browser screenshot of a replay is bench/replay_screenshot.py)."""
import base64
import re

import msgpack
import numpy as np
import pytest
from pydrake.geometry import Meshcat
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder, LeafSystem

from alight.diagrams.world.visualization import (CAMERA_OFFSET, FAR, FIT, LABEL_HEIGHT, NEAR,
                                                 add_flight_view, framing, start_recording,
                                                 three_js)
from alight.systems.boundary import GROUND_TRUTH
from alight.systems.mission.landing import MISSION_STATUS, Mode

FPS = 30.0


def replay_commands(html: str) -> list[dict]:
    """The Meshcat commands a replay's HTML carries (msgpack, base64)."""
    return [msgpack.unpackb(base64.b64decode(blob), raw=False, strict_map_key=False)
            for blob in re.findall(r"data:application/octet-binary;base64,([A-Za-z0-9+/=]+)",
                                   html)]


def tracks(commands: list[dict]) -> dict[tuple[str, str], list[dict]]:
    """Animation keys by (path, track), e.g. ("/drake", ".position")."""
    found = {}
    for command in commands:
        if command["type"] == "set_animation":
            for animation in command["animations"]:
                for track in animation["clip"]["tracks"]:
                    found[animation["path"], track["name"]] = track["keys"]
    return found


def line_vertices(command: dict) -> np.ndarray:
    position = command["object"]["geometries"][0]["data"]["attributes"]["position"]["array"]
    return np.frombuffer(position.data, "<f4").reshape(-1, 3)


def test_framing_follows_the_vehicle_and_brings_the_car_in_as_it_nears():
    p_WB, x = np.array([1.0, 2.0, 3.0]), np.array([1.0, 0.0, 0.0])
    np.testing.assert_array_equal(framing(p_WB, None)[0], p_WB)
    center, back_off = framing(p_WB, p_WB + (FAR + 1.0) * x)  # far: the vehicle alone
    np.testing.assert_array_equal(center, p_WB)
    assert back_off == 1.0
    offset = np.array([0.6 * FIT, 0.0, -0.5])  # near: the midpoint, both in view
    center, back_off = framing(p_WB, p_WB + offset)
    np.testing.assert_allclose(center, p_WB + offset / 2)
    assert back_off == 1.0
    center, back_off = framing(p_WB, p_WB + NEAR * x)
    np.testing.assert_allclose(center, p_WB + NEAR / 2 * x)
    assert back_off == pytest.approx(NEAR / FIT) and back_off > 1.0
    middle = (NEAR + FAR) / 2  # half way in: half way to the midpoint
    center, back_off = framing(p_WB, p_WB + middle * x)
    np.testing.assert_allclose(center, p_WB + middle / 4 * x)
    assert back_off == pytest.approx(max(1.0, middle / 2 / FIT))
    assert framing(p_WB, p_WB + 200.0 * x)[1] == 1.0


def motion(t: float) -> tuple[np.ndarray, np.ndarray]:
    """p_WB climbing along x, p_WT 20 m away driving towards it along y at 6 m/s."""
    return np.array([t, 0.0, 1.0 + t]), np.array([0.0, 20.0 - 6 * t, 0.5])


class Flight(LeafSystem):
    """Outputs `ground_truth` (`motion`) and `status` (the mission IDLE for 1 s, then
    TAKING_OFF)."""

    def __init__(self):
        super().__init__()
        self.DeclareVectorOutputPort("ground_truth", GROUND_TRUTH.size, self._truth)
        self.DeclareVectorOutputPort("status", MISSION_STATUS.size, self._status)

    def _truth(self, context, output):
        p_WB, p_WT = motion(context.get_time())
        output.SetFromVector(GROUND_TRUTH.vector(p_WB=p_WB, p_WT=p_WT, q_WB=[1, 0, 0, 0],
                                                 target_present=1.0))

    def _status(self, context, output):
        output.SetFromVector(MISSION_STATUS.vector(
            mode=Mode.IDLE if context.get_time() < 1.0 else Mode.TAKING_OFF))


@pytest.fixture(scope="module")
def replay() -> list[dict]:
    """The view alone on `Flight` for 2.5 s, recorded."""
    meshcat = Meshcat()
    builder = DiagramBuilder()
    flight = builder.AddSystem(Flight())
    add_flight_view(builder, meshcat, flight.GetOutputPort("ground_truth"),
                    flight.GetOutputPort("status"), MISSION_STATUS, "mode", Mode)
    simulator = Simulator(builder.Build())
    start_recording(meshcat)
    simulator.AdvanceTo(2.5)
    meshcat.StopRecording()
    meshcat.PublishRecording()
    return replay_commands(meshcat.StaticHtml())


def test_the_replay_follows_the_framed_point_and_backs_off(replay):
    commands = replay
    found = tracks(commands)
    scene, camera = found["/drake", ".position"], found["/Cameras/default/rotated/<object>",
                                                       ".position"]
    # Publish k at k * (1/30) s goes to frame floor(k * (1/30) * 30), as Drake's visualizer's:
    # 31 and 62 land on frames 30 and 61, after 30 and 61 (rounding, not the view).
    published = {int(np.floor(k * (1 / FPS) * FPS)): k for k in range(76)}
    assert [key["time"] for key in scene] == list(published)
    assert len(published) == 74
    for key in scene:
        center, _ = framing(*motion(published[key["time"]] / FPS))
        np.testing.assert_allclose(key["value"], -center, atol=1e-9)
    # The camera backs off while the car is over 8 m away (to 2.1 s), then stays: moved
    # only when it changes, so that the live view's user may turn it.
    backed_off = [k for k in published if framing(*motion(published[k] / FPS))[1] > 1.0]
    assert backed_off == [k for k in published if k <= backed_off[-1]]
    assert 2.0 < backed_off[-1] / FPS < 2.2
    assert [key["time"] for key in camera] == backed_off + [backed_off[-1] + 1]
    for key in camera:
        _, back_off = framing(*motion(published[key["time"]] / FPS))
        np.testing.assert_allclose(key["value"], three_js(back_off * CAMERA_OFFSET))
    assert camera[0]["value"][0] < CAMERA_OFFSET[0] and camera[-1]["value"][0] == CAMERA_OFFSET[0]
    # The grid (Meshcat does not draw half spaces: the ground) moves with the scene, in cells.
    grid = np.array([key["value"] for key in found["/Grid", ".position"]])
    scene_shift = np.array([key["value"] for key in scene])
    np.testing.assert_allclose((grid - scene_shift)[:, :2],
                               np.round((grid - scene_shift)[:, :2]), atol=1e-9)
    np.testing.assert_allclose(grid[:, 2], scene_shift[:, 2])
    # It opens looking at the framed point (the origin of the shifted scene).
    assert three_js(CAMERA_OFFSET) == [-5.0, 3.5, 5.0]  # three.js is y-up
    targets = [c["value"] for c in commands if c["type"] == "set_target"]
    assert targets == [[0.0, 0.0, 0.0]]


def test_the_mode_label_shows_the_mission_mode(replay):
    commands = replay
    found = tracks(commands)
    labels = {c["path"].rsplit("/", 1)[1] for c in commands if c["type"] == "set_object"
              and c["path"].startswith("/drake/flight_view/mode/")}
    assert labels == set(Mode.__members__)
    visible = {mode: [(key["time"], key["value"]) for key in
                      found[f"/drake/flight_view/mode/{mode}", ".visible"]] for mode in labels}
    assert visible.pop("IDLE") == [(0, True), (30, False)]
    assert visible.pop("TAKING_OFF") == [(0, False), (30, True)]
    assert all(keys == [(0, False)] for keys in visible.values())
    texture = next(c for c in commands if c["type"] == "set_object"
                   and c["path"].endswith("mode/TAKING_OFF"))["object"]["object"]
    assert texture["resources"]["TAKING_OFF.png"].startswith("data:image/png;base64,")
    label = found["/drake/flight_view/mode", ".position"]
    np.testing.assert_allclose(label[-1]["value"], [2.5, 0.0, 3.5 + LABEL_HEIGHT])  # above it


def test_the_paths_are_lines_shown_piece_by_piece(replay):
    commands = replay
    found = tracks(commands)
    for name, index in (("vehicle", 0), ("target", 1)):
        pieces = {int(c["path"].rsplit("/", 1)[1]): line_vertices(c) for c in commands
                  if c["type"] == "set_object"
                  and c["path"].startswith(f"/drake/flight_view/paths/{name}/")}
        assert sorted(pieces) == [0, 1, 2]  # 0-1 s, 1-2 s, 2-2.5 s (open)
        samples = np.array([motion(k / 10)[index] for k in range(26)])
        np.testing.assert_allclose(pieces[0], samples[:11], atol=1e-6)
        np.testing.assert_allclose(pieces[1], samples[10:21], atol=1e-6)
        np.testing.assert_allclose(pieces[2], samples[20:], atol=1e-6)
        for piece, frame in ((0, 30), (1, 60)):  # closed pieces appear when they close
            assert [(k["time"], k["value"]) for k in found[
                f"/drake/flight_view/paths/{name}/{piece}", ".visible"]] == [(0, False),
                                                                              (frame, True)]
        assert (f"/drake/flight_view/paths/{name}/2", ".visible") not in found


def test_a_recorded_landing_has_the_view(tmp_path):
    """The runner adds the view to a scenario's run with a Meshcat: the field landing's first
    2 s, its mission mode labelled."""
    from alight.diagrams.running.runner import run
    from alight.diagrams.scenario import load_scenario
    meshcat = Meshcat()
    run(load_scenario("field"), run_dir=tmp_path / "land", meshcat=meshcat,
        record=tmp_path / "land.html", command="land", duration=2.0)
    found = tracks(replay_commands((tmp_path / "land.html").read_text()))
    assert [(k["time"], k["value"]) for k in found["/drake/flight_view/mode/TAKING_OFF",
                                                   ".visible"]] == [(0, False), (30, True)]
    assert len(found["/drake", ".position"]) >= 60
    assert meshcat.HasPath("/drake/flight_view/paths/vehicle/1")
    assert meshcat.HasPath("/drake/flight_view/paths/target/1")


def test_the_mission_api_hover_and_track_label_their_modes(tmp_path, vehicle_config):
    """`alight fly`'s Mission labels the UAV manager's phase; a stack without a mission (hover,
    alight track) the flight controller's mode."""
    from alight.diagrams.running.mission import Mission
    from alight.diagrams.running.runner import run
    from alight.diagrams.scenario import load_scenario
    mission = Mission.simulated(seed=1, run_dir=tmp_path / "fly", meshcat=Meshcat(),
                                record=tmp_path / "fly.html", strict=False)
    with mission:
        assert mission.takeoff(1.0).done
    found = tracks(replay_commands((tmp_path / "fly.html").read_text()))
    shown = {path.rsplit("/", 1)[1]: [key["value"] for key in keys]
             for (path, track), keys in found.items()
             if path.startswith("/drake/flight_view/mode/") and track == ".visible"}
    assert shown["IDLE"][:2] == [True, False] and shown["TAKING_OFF"] == [False, True, False]
    assert shown["FLYING"] == [False, True]
    run(load_scenario("hover"), run_dir=tmp_path / "hover", meshcat=Meshcat(),
        record=tmp_path / "hover.html", command="hover", duration=1.0)
    found = tracks(replay_commands((tmp_path / "hover.html").read_text()))
    assert {path.rsplit("/", 1)[1] for path, _ in found
            if path.startswith("/drake/flight_view/mode/")} == {
                "DISARMED", "ATTITUDE_THRUST", "RATES_THRUST", "FAILSAFE_DESCENT"}
    from alight.diagrams.running.track import TrackExperiment, fly_track
    fly_track(vehicle_config, TrackExperiment(trajectory="hover", controller="se3", altitude=1.5,
                                              settle=0.0, hover_time=1.0),
              run_dir=tmp_path / "track", meshcat=Meshcat(), record=tmp_path / "track.html",
              duration=1.0, plots=False)
    found = tracks(replay_commands((tmp_path / "track.html").read_text()))
    assert [key["value"] for key in found["/drake/flight_view/mode/DISARMED", ".visible"]] == [
        True, False]  # armed at once
    assert len(found["/drake", ".position"]) >= 29
