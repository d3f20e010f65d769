"""The hover demo: the scripted pilot flies the simulated vehicle through take-off, hover and
landing on an attitude/thrust profile (no position controller)."""
import dataclasses as dc
from pathlib import Path

import numpy as np
from pydrake.systems.framework import DiagramBuilder

from alight.diagrams.running.paths import default_run_dir
from alight.diagrams.running.run_log import RunLog, RunLoggers, add_run_logging, write_run_folder
from alight.diagrams.world.sim_vehicle import SimVehicleConfig, make_sim_vehicle
from alight.diagrams.running.simulation import simulate
from alight.models import model_path
from alight.systems.control.scripted_pilot import PilotModel, PilotProfile, ScriptedPilot
from alight.systems.params import load_params
from alight.systems.rotations import tilt_deg
from alight.systems.plant.hexacopter import load_hexacopter_params


def load_pilot_profile(filename: str = "hover_profile.yaml") -> PilotProfile:
    return load_params(PilotProfile, model_path(filename))


def pilot_model(config: SimVehicleConfig) -> PilotModel:
    """The pilot's knowledge of the vehicle: mass, thrust curve and vertical drag of its model."""
    from pydrake.multibody.plant import MultibodyPlant
    from alight.systems.plant.hexacopter import add_hexacopter, airframe
    params = load_hexacopter_params(config.vehicle)
    plant = MultibodyPlant(0.0)
    add_hexacopter(plant, params)
    plant.Finalize()
    frame = airframe(plant, params)
    return PilotModel(mass=frame.mass, curve=frame.thrust_curve,
                      drag_linear=params.drag_linear[2], drag_quadratic=params.drag_quadratic[2])


@dc.dataclass
class HoverSummary:
    run_dir: Path
    max_altitude: float        # m above the resting height
    hover_altitude_std: float  # m, during the hover segment
    max_tilt: float            # deg
    touchdown_speed: float     # m/s, vertical, at the first ground contact after the flight
    disarmed_at_end: bool

    def lines(self) -> list[str]:
        return [f"max altitude      {self.max_altitude:6.2f} m",
                f"hover altitude sd {self.hover_altitude_std:6.3f} m",
                f"max tilt          {self.max_tilt:6.2f} deg",
                f"touchdown speed   {self.touchdown_speed:6.2f} m/s",
                f"disarmed at end   {self.disarmed_at_end}",
                f"run folder        {self.run_dir}"]


def add_pilot_onboard(builder, vehicle, profile: PilotProfile, model: PilotModel,
                      stop_at: float | None = None) -> RunLoggers:
    """The onboard side of `alight hover` on `vehicle`'s ports (simulated or MAVLink): the
    scripted pilot commanding it, and the run logging."""
    pilot = builder.AddNamedSystem("pilot", ScriptedPilot(profile, model, stop_at=stop_at))
    builder.Connect(pilot.GetOutputPort("fc_command"), vehicle.GetInputPort("fc_command"))
    return add_run_logging(builder, vehicle, pilot.GetOutputPort("fc_command"))


def fly_profile(config: SimVehicleConfig, profile: PilotProfile, seed: int = 0,
                run_dir: str | Path | None = None, meshcat=None, record=None,
                realtime_rate: float = 0.0, duration: float | None = None,
                pilot_stops_at: float | None = None, command: str = "hover") -> RunLog:
    """Flies `profile` with the scripted pilot on the simulated vehicle; returns the run log.
    `pilot_stops_at` freezes the pilot's output from that time (a companion computer that dies)."""
    builder = DiagramBuilder()
    vehicle = builder.AddNamedSystem("vehicle", make_sim_vehicle(config, meshcat))
    loggers = add_pilot_onboard(builder, vehicle, profile, pilot_model(config), pilot_stops_at)
    diagram = builder.Build()
    duration = profile.duration if duration is None else duration
    simulator = simulate(diagram, duration, seed, meshcat, record, realtime_rate)
    run_dir = Path(run_dir) if run_dir is not None else default_run_dir(command, seed)
    write_run_folder(run_dir, loggers, simulator.get_context(), {
        "command": command, "seed": seed, "duration": duration,
        "config": config, "profile": profile, "pilot_stops_at": pilot_stops_at})
    return RunLog(run_dir)


def run_hover(config: SimVehicleConfig, profile: PilotProfile, seed: int = 0,
              run_dir: str | Path | None = None, meshcat=None, record=None,
              realtime_rate: float = 0.0) -> HoverSummary:
    """The hover demo (`alight hover`): flies the profile and summarizes the flight."""
    run = fly_profile(config, profile, seed, run_dir, meshcat, record, realtime_rate)
    return summarize_hover(run, profile)


def summarize_hover(run: RunLog, profile: PilotProfile) -> HoverSummary:
    truth = run["ground_truth"]
    z = truth["p_WB_2"].to_numpy()
    z0 = z[0]
    t = truth["time"].to_numpy()
    # The hover segment is the longest segment with zero vertical acceleration while armed.
    starts = np.cumsum([0.0] + [s.duration for s in profile.segments])
    hover = max(range(len(profile.segments)), key=lambda i: profile.segments[i].duration
                if profile.segments[i].arm and profile.segments[i].vertical_acceleration == 0.0
                and starts[i] < 15 else -1)
    in_hover = (t >= starts[hover] + 1.0) & (t <= starts[hover + 1])
    q = run.field("ground_truth", "q_WB").to_numpy()
    tilt = tilt_deg(q)
    vz = truth["v_WB_2"].to_numpy()
    airborne = np.flatnonzero(z > z0 + 0.3)
    touchdown_speed = 0.0
    if len(airborne):
        after = np.flatnonzero((t > t[airborne[-1]]) & (z < z0 + 0.01))
        if len(after):
            touchdown_speed = float(abs(vz[max(after[0] - 1, 0)]))
    status = run["fc_status"]
    return HoverSummary(run.path, float(z.max() - z0),
                        float(np.std(z[in_hover])) if in_hover.any() else float("nan"),
                        float(tilt.max()), touchdown_speed, bool(status["armed"].iloc[-1] < 0.5))
