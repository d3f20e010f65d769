"""The managed flight stack of M Sec. 7 on any vehicle's boundary ports: `add_managed_onboard`
builds odometry -> control manager (its trackers and controllers from models/control_manager.yaml, M
Sec. 7.2) -> `fc_command`, driven by the UAV manager (M Sec. 7.6) whose `command` input is exported
as the diagram's `uav_command` (the mission API of diagrams/running/mission.py sets it);
`FlightPlan` is what `alight fly` flies."""
import dataclasses as dc

import numpy as np

from alight.diagrams.onboard.control_manager import (GOAL_KINDS, ControlManagerConfig,
                                                     ManagedControllers, add_control_manager,
                                                     add_managed_logging, connect_managed_vehicle)
from alight.diagrams.onboard.controllers import ControllersConfig
from alight.diagrams.running.run_log import RunLoggers
from alight.models import model_path
from alight.systems.managers.constraint_manager import (CONSTRAINT_STATUS, ConstraintManager,
                                                        ConstraintManagerParams,
                                                        make_constraint_manager)
from alight.systems.managers.uav_manager import UAV_STATUS, UavManager, UavManagerParams
from alight.systems.params import ConfigError, load_params


def load_uav_manager_params(filename: str = "uav_manager.yaml") -> UavManagerParams:
    """A path, or a file name in models/; raises ConfigError naming the file and the key."""
    return load_params(UavManagerParams, model_path(filename))


@dc.dataclass
class ManagedOnboard:
    """Handles to the managed stack built by `add_managed_onboard`."""
    vehicle: object
    state_estimate: object           # the STATE_ESTIMATE port the stack flies on
    managed: ManagedControllers
    uav: UavManager
    loggers: RunLoggers
    groups: ConstraintManager


def add_managed_onboard(builder, vehicle, config: ControlManagerConfig,
                        uav_params: UavManagerParams, constraint_params: ConstraintManagerParams,
                        odometry, controllers_config: ControllersConfig | None = None,
                        schedule: list[tuple[float, str]] | None = None,
                        estimate_filter=None) -> ManagedOnboard:
    """The managed stack `config` (its controllers with `controllers_config` when given, else
    `config.controller_params`), the UAV manager `uav_params` and the constraint manager
    `constraint_params` on `vehicle`'s boundary ports (simulated or MAVLink). `odometry` as in
    diagrams/onboard/mpc_loop.py `add_mpc_control`; `schedule` the control manager's timed
    controller switches; `estimate_filter(builder, port) -> port` may alter the estimate (fault
    injection in tests). Exports the UAV manager's command input as `uav_command`."""
    controllers_config = controllers_config or config.controller_params
    estimate = odometry(builder, vehicle)
    if estimate_filter is not None:
        estimate = estimate_filter(builder, estimate)
    groups = builder.AddNamedSystem("constraint_manager",
                                    make_constraint_manager(constraint_params))
    uav = builder.AddNamedSystem("uav_manager", UavManager(
        uav_params, config.names, config.tracker_names,
        config.safety_area if config.safety_area.enabled else None,
        groups.constraint_group_names, groups.gain_group_names))
    managed = add_control_manager(
        builder, config, controllers_config, estimate,
        switch_request=uav.GetOutputPort("switch_request"), schedule=schedule,
        goals={kind: uav.GetOutputPort(f"{kind}_goal") for kind in GOAL_KINDS
               if uav.HasOutputPort(f"{kind}_goal")},   # not its kinds (target) hold
        fc_attitude=vehicle.GetOutputPort("fc_attitude"))
    manager = managed.manager
    _connect_groups(builder, groups, estimate, uav, managed)
    builder.Connect(estimate, uav.GetInputPort("state_estimate"))
    builder.Connect(vehicle.GetOutputPort("fc_status"), uav.GetInputPort("fc_status"))
    builder.Connect(manager.GetOutputPort("manager_status"), uav.GetInputPort("manager_status"))
    landing = managed.trackers[uav.params.landing_tracker]
    if landing.HasOutputPort("landed"):
        builder.Connect(landing.GetOutputPort("landed"), uav.GetInputPort("landed"))
    connect_managed_vehicle(builder, managed, vehicle, uav.GetOutputPort("arm"),
                            uav.GetOutputPort("tracker_request"), odometry, estimate)
    builder.ExportInput(uav.GetInputPort("command"), "uav_command")
    loggers = add_managed_logging(builder, vehicle, managed, estimate,
                                  manager.GetOutputPort("reference"), config.period)
    loggers.add(builder, "uav_status", uav.GetOutputPort("uav_status"), UAV_STATUS,
                uav.params.period)
    loggers.add(builder, "constraint_status", groups.GetOutputPort("constraint_status"),
                CONSTRAINT_STATUS, uav.params.period)
    return ManagedOnboard(vehicle, estimate, managed, uav, loggers, groups)


def _connect_groups(builder, groups: ConstraintManager, estimate, uav, managed) -> None:
    """The constraint manager (M Sec. 7.5) between the UAV manager's requests and the trackers'
    `constraint_group` / controllers' `gain_group` inputs."""
    builder.Connect(estimate, groups.GetInputPort("state_estimate"))
    builder.Connect(uav.GetOutputPort("group_request"), groups.GetInputPort("request"))
    for name, tracker in managed.trackers.items():
        if tracker.HasInputPort("constraint_group"):
            if list(getattr(tracker, "group_names", [])) != groups.constraint_group_names:
                raise ConfigError(f"tracker {name!r} indexes constraint groups "
                                  f"{getattr(tracker, 'group_names', None)}, the constraint "
                                  f"manager {groups.constraint_group_names}: use one "
                                  f"constraints file")
            builder.Connect(groups.GetOutputPort("constraint_group"),
                            tracker.GetInputPort("constraint_group"))
    for controller in managed.controllers.values():
        if controller.HasInputPort("gain_group"):
            builder.Connect(groups.GetOutputPort("gain_group"),
                            controller.GetInputPort("gain_group"))


def read_trajectory_file(path) -> tuple[np.ndarray, float | None]:
    """A CSV file with a header: columns x, y, z (and heading) are waypoints a trajectory is
    generated through (M Sec. 6); with a column t [s, uniformly spaced] the rows are a sampled
    trajectory flown as it is. Returns (rows [x, y, z, heading], sample period or None);
    raises ValueError naming the file and what is wrong."""
    import pandas as pd
    try:
        table = pd.read_csv(path, skipinitialspace=True)
    except (OSError, ValueError) as e:
        raise ValueError(f"{path}: cannot read the trajectory CSV: {e}") from None
    missing = [c for c in ("x", "y", "z") if c not in table.columns]
    if missing or len(table) < 1:
        raise ValueError(f"{path}: a header with columns x, y, z (heading, t optional) and at "
                         f"least one row is needed; missing {missing}")
    heading = table["heading"] if "heading" in table.columns else 0.0
    rows = np.column_stack([table["x"], table["y"], table["z"],
                            np.broadcast_to(heading, len(table))]).astype(float)
    if not np.all(np.isfinite(rows)):
        raise ValueError(f"{path}: every x, y, z, heading must be a finite number")
    if "t" not in table.columns:
        return rows, None
    t = table["t"].to_numpy(float)
    steps = np.diff(t)
    if len(t) < 2 or not np.all(np.isfinite(t)) or steps.min() <= 0 \
            or np.ptp(steps) > 1e-6 * max(1.0, steps.mean()):
        raise ValueError(f"{path}: column t must be at least two increasing, uniformly "
                         f"spaced times [s]")
    return rows, float(steps.mean())


@dc.dataclass
class FlightPlan:
    """What `alight fly` flies: take off to `takeoff_height`, then through `waypoints` (rows
    x, y, z(, heading), a generated trajectory) or a sampled trajectory (`samples` every
    `sample_period` s), then land here."""
    waypoints: np.ndarray | None = None
    samples: np.ndarray | None = None
    sample_period: float | None = None
    takeoff_height: float = 2.0
    constraints: str | None = None      # the trajectory's constraint group (M Sec. 7.5)
