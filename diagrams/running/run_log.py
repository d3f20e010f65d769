"""Run folders: every run writes its signals and its configuration, readable with pandas.

Layout of a run folder (docs/run_folder.md):
    metadata.json        command, seed, configuration, versions, and per stream its columns
    <stream>.parquet     one table per logged signal, a `time` column [s] plus named columns
Streams: `fc_command`, `fc_status`, `fc_attitude`, `ground_truth` (VectorLogSink at a fixed
period), `imu` (every IMU sample exactly once, with its sequence number and timestamp) and
`timing` (the wall-clock compute times of the systems' `compute_timer`s, alight.systems.timing:
the one stream a rerun with the same seed does not reproduce).
"""
import dataclasses as dc
import datetime
import json
from importlib import metadata as importlib_metadata
from pathlib import Path

import numpy as np
import pandas as pd
from pydrake.systems.framework import LeafSystem
from pydrake.systems.primitives import VectorLogSink

from alight.systems.boundary import (FC_ATTITUDE, FC_COMMAND, FC_STATUS, GROUND_TRUTH, ImuSamples,
                                     VectorLayout)
from alight.systems.timing import ComputeTimer, compute_timers, timing_frame

FORMAT_VERSION = 1


class ImuLogSink(LeafSystem):
    """Input `imu` ImuSamples; records each sample once (by sequence number) at every `period`."""

    def __init__(self, period: float):
        super().__init__()
        from pydrake.common.value import AbstractValue
        self._imu = self.DeclareAbstractInputPort("imu", AbstractValue.Make(ImuSamples.empty()))
        self.DeclarePeriodicPublishEvent(period, 0.0, self._record)
        self.DeclareForcedPublishEvent(self._record)
        self.samples: list[ImuSamples] = []
        self._last_seq = -1

    def _record(self, context):
        new = self._imu.Eval(context).newer_than(self._last_seq)
        if len(new):
            self.samples.append(new)
            self._last_seq = int(new.seq[-1])

    def frame(self) -> pd.DataFrame:
        if not self.samples:
            return pd.DataFrame(columns=["time", "seq", *IMU_COLUMNS])
        seq = np.concatenate([s.seq for s in self.samples])
        return pd.DataFrame({
            "time": np.concatenate([s.t for s in self.samples]), "seq": seq,
            **dict(zip(IMU_COLUMNS, np.hstack([np.vstack([s.accel for s in self.samples]),
                                               np.vstack([s.gyro for s in self.samples])]).T))})


IMU_COLUMNS = ["accel_x", "accel_y", "accel_z", "gyro_x", "gyro_y", "gyro_z"]


@dc.dataclass
class RunLoggers:
    """The sinks of a run's streams, and the compute timers of parts outside the diagram (by
    component name; those of its systems are collected from the diagram)."""
    vector_sinks: dict[str, tuple[VectorLogSink, VectorLayout]]
    imu_sink: ImuLogSink | None
    timers: dict[str, ComputeTimer] = dc.field(default_factory=dict)

    def add(self, builder, name: str, port, layout: VectorLayout, period: float = 0.01) -> None:
        """Logs one more vector port as stream `name`."""
        sink = builder.AddNamedSystem(f"log_{name}", VectorLogSink(layout.size, period))
        builder.Connect(port, sink.get_input_port())
        self.vector_sinks[name] = (sink, layout)


def add_run_logging(builder, vehicle, command_port=None, period: float = 0.01) -> RunLoggers:
    """Logs the vehicle's vector outputs, its IMU and (if given) the command sent to it."""
    ports = {"fc_status": (vehicle.GetOutputPort("fc_status"), FC_STATUS),
             "fc_attitude": (vehicle.GetOutputPort("fc_attitude"), FC_ATTITUDE)}
    if vehicle.HasOutputPort("ground_truth"):
        ports["ground_truth"] = (vehicle.GetOutputPort("ground_truth"), GROUND_TRUTH)
    if command_port is not None:
        ports["fc_command"] = (command_port, FC_COMMAND)
    imu_sink = builder.AddNamedSystem("log_imu", ImuLogSink(period=0.1))
    builder.Connect(vehicle.GetOutputPort("imu"), imu_sink.get_input_port())
    loggers = RunLoggers({}, imu_sink)
    for name, (port, layout) in ports.items():
        loggers.add(builder, name, port, layout, period)
    return loggers


def _versions() -> dict:
    versions = {}
    for package in ("alight", "drake", "numpy"):
        try:
            versions[package] = importlib_metadata.version(package)
        except importlib_metadata.PackageNotFoundError:
            versions[package] = None
    return versions


def _jsonable(value):
    if dc.is_dataclass(value):
        return {k: _jsonable(v) for k, v in dc.asdict(value).items()}
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    return value


def write_run_folder(path: str | Path, loggers: RunLoggers, simulator, run_metadata: dict
                     ) -> Path:
    """Writes every logged stream of `simulator`'s run as Parquet, the `timing` stream of its
    diagram's compute timers (and `loggers.timers`), and metadata.json (config, seed, versions,
    columns)."""
    path = Path(path)
    root_context = simulator.get_context()
    path.mkdir(parents=True, exist_ok=True)
    streams = {}
    for name, (sink, layout) in loggers.vector_sinks.items():
        log = sink.FindLog(root_context)
        frame = pd.DataFrame(log.data().T, columns=layout.names())
        frame.insert(0, "time", log.sample_times())
        frame.to_parquet(path / f"{name}.parquet", index=False)
        streams[name] = {"file": f"{name}.parquet", "columns": ["time", *layout.names()],
                         "fields": dict(layout.fields), "rows": len(frame)}
    if loggers.imu_sink is not None:
        loggers.imu_sink.ForcedPublish(loggers.imu_sink.GetMyContextFromRoot(root_context))
        frame = loggers.imu_sink.frame()
        frame.to_parquet(path / "imu.parquet", index=False)
        streams["imu"] = {"file": "imu.parquet", "columns": list(frame.columns), "rows": len(frame)}
    frame = timing_frame({**compute_timers(simulator.get_system()), **loggers.timers})
    frame.to_parquet(path / "timing.parquet", index=False)
    streams["timing"] = {"file": "timing.parquet", "columns": list(frame.columns),
                         "rows": len(frame)}
    document = {"format_version": FORMAT_VERSION,
                "created": datetime.datetime.now(datetime.timezone.utc).isoformat(),
                "versions": _versions(), "streams": streams, **_jsonable(run_metadata)}
    (path / "metadata.json").write_text(json.dumps(document, indent=2))
    return path


class RunLog:
    """A run folder read back: `run.metadata` (dict) and `run["ground_truth"]` (DataFrame)."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        metadata_file = self.path / "metadata.json"
        if not metadata_file.is_file():
            raise FileNotFoundError(f"{self.path} is not a run folder: no metadata.json")
        self.metadata = json.loads(metadata_file.read_text())
        self._frames: dict[str, pd.DataFrame] = {}

    @property
    def streams(self) -> list[str]:
        return list(self.metadata["streams"])

    def __getitem__(self, stream: str) -> pd.DataFrame:
        if stream not in self.metadata["streams"]:
            raise KeyError(f"{self.path}: no stream '{stream}' (has {self.streams})")
        if stream not in self._frames:
            self._frames[stream] = pd.read_parquet(self.path / self.metadata["streams"][stream]
                                                   ["file"])
        return self._frames[stream]

    def field(self, stream: str, field: str) -> pd.DataFrame:
        """The columns of one field, e.g. `run.field("ground_truth", "p_WB")` (x, y, z)."""
        frame = self[stream]
        size = self.metadata["streams"][stream]["fields"][field]
        columns = [field] if size == 1 else [f"{field}_{i}" for i in range(size)]
        return frame[columns]

    def compute_seconds(self, component: str, part: str | None = None) -> np.ndarray:
        """Wall-clock seconds of each measured call of `component` (of `part` only, when given),
        from the `timing` stream, e.g. `run.compute_seconds("vio", "backend")`."""
        timing = self["timing"]
        rows = timing["component"] == component
        if part is not None:
            rows &= timing["part"] == part
        return timing["seconds"][rows].to_numpy()


def read_run(path: str | Path) -> RunLog:
    return RunLog(path)
