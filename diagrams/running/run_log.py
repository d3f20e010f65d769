"""Run folders: every run writes its signals and its configuration, readable with pandas.

Layout of a run folder (docs/run_folder.md):
    metadata.json        command, seed, configuration, versions, per stream its file and columns,
                         `complete` (false until the run has finished)
    <stream>.parquet     one table per logged signal, a `time` column [s] plus named columns
    <stream>.arrows      the same rows while the run goes (and for good if it died): an Arrow IPC
                         stream, one record batch per flush
Streams: `fc_command`, `fc_status`, `fc_attitude`, `ground_truth` (sampled at a fixed period),
`imu` (every IMU sample exactly once, with its sequence number and timestamp) and `timing` (the
wall-clock compute times of the systems' `compute_timer`s, alight.systems.timing: the one stream
a rerun with the same seed does not reproduce).

Streams are written while the run goes, so that a run that dies (a crash, kill -9, a power cut)
leaves a folder readable up to its last flush: each sink holds only the rows recorded since the
last flush; the run folder writer, a LeafSystem of the logged diagram, appends them (and the
compute times measured since) to the stream files every `FLUSH_PERIOD` of simulated time, which is
about every second of wall time in a real-time run (fsync at most every `FSYNC_PERIOD` of wall
time). `open_run_folder` starts the folder before the simulation; `write_run_folder` ends it:
the last rows, each stream converted to Parquet, metadata.json completed. The reader (`RunLog`)
reads a finished folder's Parquet files and an unfinished one's Arrow streams up to their last
complete batch, with a `RunFolderWarning`; what it cannot read is a `RunFolderError` naming the
file and the stream.
"""
import dataclasses as dc
import datetime
import json
import logging
import os
import threading
import warnings
from importlib import metadata as importlib_metadata
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import Diagram, LeafSystem

from alight.systems.boundary import (FC_ATTITUDE, FC_COMMAND, FC_STATUS, GROUND_TRUTH, RANGE,
                                     ImuSamples, VectorLayout)
from alight.systems.timing import ComputeTimer, compute_timers, timing_frame

LOG = logging.getLogger("alight.run_log")

FORMAT_VERSION = 1
FLUSH_PERIOD = 1.0   # s of simulated time between two appends to the stream files
FSYNC_PERIOD = 1.0   # s of wall time between two fsyncs of the stream files (power cuts)
ROW_GROUP = 65536    # rows per Parquet row group when a stream is converted


class RunFolderError(Exception):
    """A run folder, or one of its files, that cannot be read; the message names the file (and
    the stream)."""


class RunFolderFileMissing(RunFolderError, FileNotFoundError):
    """A file of a run folder (metadata.json, a stream's file) is not there."""


class RunFolderWarning(UserWarning):
    """A stream read back in part: its run did not finish, or its file ends cut short."""


class StreamBuffer:
    """The rows [time, value...] of one vector stream recorded and not taken yet: `take()`
    empties it. The run folder writer takes the rows at every flush, so a buffer holds at most
    one flush period of them (all of them while no run folder is open)."""

    def __init__(self, size: int):
        self._rows = np.empty((128, 1 + size))
        self.pending = 0  # rows recorded and not taken yet

    def append(self, t: float, value: np.ndarray) -> None:
        if self.pending == len(self._rows):
            self._rows = np.concatenate([self._rows, np.empty_like(self._rows)])
        row = self._rows[self.pending]
        row[0] = t
        row[1:] = value
        self.pending += 1

    def take(self) -> np.ndarray:
        """The rows recorded since the last call, [time, data...] each."""
        rows = self._rows[:self.pending].copy()
        self.pending = 0
        return rows


class VectorStreamRecorder(LeafSystem):
    """The run's vector streams, one input port each (named as the stream, added by `add`):
    records [time, value] of the streams of one period at that period's publish event (every
    `period` from t = 0, as Drake's VectorLogSink) and of all of them at a forced publish, into
    their `StreamBuffer`s. One Python call per period and tick for all its streams, where one
    sink per stream made one call each (a landing logs ten streams at 100 Hz)."""

    def __init__(self):
        super().__init__()
        self._groups: dict[float, list] = {}   # period -> [(input port, buffer), ...]
        self.DeclareForcedPublishEvent(self._record_all)

    def add(self, name: str, size: int, period: float):
        """(the new input port `name`, its StreamBuffer), recorded every `period`."""
        port = self.DeclareVectorInputPort(name, size)
        buffer = StreamBuffer(size)
        group = self._groups.get(period)
        if group is None:
            group = self._groups[period] = []
            self.DeclarePeriodicPublishEvent(
                period, 0.0, lambda context, group=group: self._record(context, group))
        group.append((port, buffer))
        return port, buffer

    @staticmethod
    def _record(context, group) -> None:
        t = context.get_time()
        for port, buffer in group:
            buffer.append(t, port.Eval(context))

    def _record_all(self, context) -> None:
        for group in self._groups.values():
            self._record(context, group)


class ImuLogSink(LeafSystem):
    """Input `imu` ImuSamples; records each sample once (by sequence number) at every `period`
    and at a forced publish, into a buffer that `take()` empties (as StreamBuffer)."""

    def __init__(self, period: float):
        super().__init__()
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

    @property
    def pending(self) -> int:
        return sum(len(s) for s in self.samples)

    def frame(self) -> pd.DataFrame:
        """The samples recorded and not taken yet: time, seq, accel_x..z, gyro_x..z."""
        if not self.samples:
            return pd.DataFrame({"time": np.zeros(0), "seq": np.zeros(0, np.int64),
                                 **{name: np.zeros(0) for name in IMU_COLUMNS}})
        seq = np.concatenate([s.seq for s in self.samples])
        return pd.DataFrame({
            "time": np.concatenate([s.t for s in self.samples]), "seq": seq,
            **dict(zip(IMU_COLUMNS, np.hstack([np.vstack([s.accel for s in self.samples]),
                                               np.vstack([s.gyro for s in self.samples])]).T))})

    def take(self) -> pd.DataFrame:
        """`frame()`, emptying the buffer."""
        frame = self.frame()
        self.samples = []
        return frame


IMU_COLUMNS = ["accel_x", "accel_y", "accel_z", "gyro_x", "gyro_y", "gyro_z"]
IMU_SCHEMA = pa.schema([("time", pa.float64()), ("seq", pa.int64()),
                        *[(name, pa.float64()) for name in IMU_COLUMNS]])
TIMING_SCHEMA = pa.schema([("time", pa.float64()), ("component", pa.string()),
                           ("part", pa.string()), ("seconds", pa.float64())])


class RunFolderWriter(LeafSystem):
    """No ports. Every `flush_period` of simulated time (from t = 0) and at a forced publish,
    appends the rows the run's sinks recorded and the compute times its timers measured since
    the last flush to the open run folder (`RunLoggers.folder`); nothing while none is open."""

    def __init__(self, loggers: "RunLoggers", flush_period: float):
        super().__init__()
        self._loggers = loggers
        self.DeclarePeriodicPublishEvent(flush_period, 0.0, self._flush)
        self.DeclareForcedPublishEvent(self._flush)

    def _flush(self, context):
        self._loggers.flush()


@dc.dataclass
class RunLoggers:
    """The sinks of a run's streams, the compute timers of parts outside the diagram (by
    component name; those of its systems are collected from the diagram), the writer that
    flushes them, and the run folder they go to once `open_run_folder` has opened it."""
    vector_sinks: dict[str, tuple[StreamBuffer, VectorLayout]]
    imu_sink: ImuLogSink | None
    timers: dict[str, ComputeTimer] = dc.field(default_factory=dict)
    writer: RunFolderWriter | None = None
    folder: "RunFolder | None" = None
    diagram_timers: dict[str, ComputeTimer] = dc.field(default_factory=dict)
    recorder: VectorStreamRecorder | None = None   # with the first stream

    def add(self, builder, name: str, port, layout: VectorLayout, period: float = 0.01) -> None:
        """Logs one more vector port as stream `name` (on the run's `VectorStreamRecorder`,
        added to `builder` with the first stream)."""
        if name in self.vector_sinks:
            raise ValueError(f"the run already logs a stream named {name!r}")
        if self.recorder is None:
            self.recorder = builder.AddNamedSystem("log_streams", VectorStreamRecorder())
        recorder_port, buffer = self.recorder.add(name, layout.size, period)
        builder.Connect(port, recorder_port)
        self.vector_sinks[name] = (buffer, layout)

    def all_timers(self) -> dict[str, ComputeTimer]:
        return {**self.diagram_timers, **self.timers}

    def schemas(self) -> dict[str, tuple[pa.Schema, dict]]:
        """Per stream: its Arrow schema and its metadata entry (file, columns, fields)."""
        streams = {}
        for name, (_, layout) in self.vector_sinks.items():
            schema = pa.schema([("time", pa.float64())]
                               + [(column, pa.float64()) for column in layout.names()])
            streams[name] = (schema, {"fields": dict(layout.fields)})
        if self.imu_sink is not None:
            streams["imu"] = (IMU_SCHEMA, {})
        streams["timing"] = (TIMING_SCHEMA, {})
        return {name: (schema, {"file": f"{name}.parquet", "columns": schema.names, **extra})
                for name, (schema, extra) in streams.items()}

    def flush(self) -> None:
        """Appends what was recorded since the last flush to the open run folder (if any). A
        write that fails (a full disk) does not stop the run, which may be flying: it is logged
        once, later rows are dropped and `write_run_folder` raises at the end."""
        if self.folder is None or self.folder.failure is not None:
            return
        try:
            self._append_pending()
        except OSError as e:
            self.folder.failure = e
            LOG.error("run folder %s: writing failed (%s); the rest of the run is not logged",
                      self.folder.path, e)

    def _append_pending(self) -> None:
        """The IMU and the compute times first, then the vector streams: the two slow tables
        (pandas conversions) written last left a wide window in which a reader already saw a
        flush's vector streams while a kill left them a flush behind (and a compute time measured
        at the flush instant goes with the next flush: one tick more)."""
        if self.imu_sink is not None:
            frame = self.imu_sink.take()
            if len(frame):
                self.folder.append("imu", pa.Table.from_pandas(
                    frame, schema=IMU_SCHEMA, preserve_index=False))
        timers = self.all_timers()
        frame = timing_frame(timers)
        for timer in timers.values():
            timer.clear()
        if len(frame):
            self.folder.append("timing", pa.Table.from_pandas(
                frame, schema=TIMING_SCHEMA, preserve_index=False))
        for name, (sink, _) in self.vector_sinks.items():
            rows = sink.take()
            if len(rows):
                self.folder.append(name, pa.RecordBatch.from_arrays(
                    [pa.array(rows[:, k]) for k in range(rows.shape[1])],
                    schema=self.folder.schemas[name]))


def add_run_logging(builder, vehicle, command_port=None, period: float = 0.01,
                    flush_period: float = FLUSH_PERIOD) -> RunLoggers:
    """Logs the vehicle's vector outputs, its IMU and (if given) the command sent to it, with the
    writer that flushes every stream to the run folder every `flush_period` once it is open."""
    ports = {"fc_status": (vehicle.GetOutputPort("fc_status"), FC_STATUS),
             "fc_attitude": (vehicle.GetOutputPort("fc_attitude"), FC_ATTITUDE),
             "range": (vehicle.GetOutputPort("range"), RANGE)}
    if vehicle.HasOutputPort("ground_truth"):
        ports["ground_truth"] = (vehicle.GetOutputPort("ground_truth"), GROUND_TRUTH)
    if command_port is not None:
        ports["fc_command"] = (command_port, FC_COMMAND)
    imu_sink = builder.AddNamedSystem("log_imu", ImuLogSink(period=0.1))
    builder.Connect(vehicle.GetOutputPort("imu"), imu_sink.get_input_port())
    loggers = RunLoggers({}, imu_sink)
    for name, (port, layout) in ports.items():
        loggers.add(builder, name, port, layout, period)
    loggers.writer = builder.AddNamedSystem("run_folder_writer",
                                            RunFolderWriter(loggers, flush_period))
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


class RunFolder:
    """A run folder being written: metadata.json (`complete`: false) at once, then one Arrow IPC
    stream file per stream (`<stream>.arrows`), appended to at every flush and converted to
    `<stream>.parquet` by `finish`."""

    def __init__(self, path: Path, schemas: dict[str, tuple[pa.Schema, dict]],
                 run_metadata: dict):
        self.path = path
        path.mkdir(parents=True, exist_ok=True)
        self.schemas = {name: schema for name, (schema, _) in schemas.items()}
        self.rows = dict.fromkeys(schemas, 0)
        self.document = {"format_version": FORMAT_VERSION,
                         "created": datetime.datetime.now(datetime.timezone.utc).isoformat(),
                         "versions": _versions(), "complete": False,
                         "streams": {name: entry for name, (_, entry) in schemas.items()},
                         **_jsonable(run_metadata)}
        self._files, self._writers = {}, {}
        for name, schema in self.schemas.items():
            (path / f"{name}.parquet").unlink(missing_ok=True)  # a previous run's, if any
            file = open(self.partial_file(name), "wb", buffering=0)
            self._files[name] = file
            self._writers[name] = pa.ipc.new_stream(file, schema)
            # An empty batch puts the schema in the file now (readable before any row is).
            self._writers[name].write_batch(pa.RecordBatch.from_pylist([], schema=schema))
        self._write_metadata()
        self.failure: OSError | None = None
        # fsync in a thread of its own: the simulation does not wait for the disk.
        self._appended = threading.Event()
        self._stop = threading.Event()
        self._syncer = threading.Thread(target=self._sync_loop, name="run-folder-fsync",
                                        daemon=True)
        self._syncer.start()

    def partial_file(self, name: str) -> Path:
        return self.path / f"{name}.arrows"

    def append(self, name: str, batch: pa.RecordBatch | pa.Table) -> None:
        """Writes `batch` to the stream's file: with the operating system at once (unbuffered:
        a killed process loses nothing of it), on the disk within `FSYNC_PERIOD`. A table (a
        pandas frame's: pandas 3 keeps strings as chunked Arrow arrays) is written batch by
        batch."""
        self._writers[name].write(batch)
        self.rows[name] += batch.num_rows
        self._appended.set()

    def _sync_loop(self) -> None:
        while not self._stop.wait(FSYNC_PERIOD):
            if self._appended.is_set():
                self._appended.clear()
                try:
                    for file in self._files.values():
                        os.fsync(file.fileno())
                except (OSError, ValueError) as e:  # a full disk; a file closed under it
                    LOG.error("run folder %s: fsync failed (%s)", self.path, e)

    def finish(self, run_metadata: dict) -> None:
        """Closes the stream files, converts each to Parquet (row groups of `ROW_GROUP` rows,
        never the whole stream in memory), removes them and completes metadata.json."""
        self._stop.set()
        self._syncer.join()
        for name, writer in self._writers.items():
            writer.close()
            self._files[name].close()
        if self.failure is not None:
            raise RunFolderError(f"{self.path}: writing the streams failed during the run "
                                 f"({self.failure}); it holds what was written before")
        for name, schema in self.schemas.items():
            partial, final = self.partial_file(name), self.path / f"{name}.parquet"
            temporary = final.with_suffix(".parquet.tmp")
            with pa.OSFile(str(partial), "rb") as source, pq.ParquetWriter(temporary,
                                                                          schema) as parquet:
                batches, count = [], 0
                for batch in pa.ipc.open_stream(source):
                    batches.append(batch)
                    count += batch.num_rows
                    if count >= ROW_GROUP:
                        parquet.write_table(pa.Table.from_batches(batches, schema))
                        batches, count = [], 0
                if batches:
                    parquet.write_table(pa.Table.from_batches(batches, schema))
            with open(temporary, "rb") as written:
                os.fsync(written.fileno())  # on the disk before it replaces the Arrow stream
            os.replace(temporary, final)
            partial.unlink()
            self.document["streams"][name]["rows"] = self.rows[name]
        self.document.update(_jsonable(run_metadata))
        self.document["complete"] = True
        self._write_metadata()

    def _write_metadata(self) -> None:
        """metadata.json replaced whole (written aside, synced, renamed), never half written."""
        temporary = self.path / "metadata.json.tmp"
        with open(temporary, "w") as file:
            file.write(json.dumps(self.document, indent=2))
            file.flush()
            os.fsync(file.fileno())
        os.replace(temporary, self.path / "metadata.json")
        directory = os.open(self.path, os.O_RDONLY)
        try:
            os.fsync(directory)
        finally:
            os.close(directory)


def open_run_folder(path: str | Path, loggers: RunLoggers, diagram: Diagram,
                    run_metadata: dict) -> Path:
    """Starts the run folder of `loggers` before the simulation of `diagram` (whose compute
    timers go to `timing`): metadata.json with `run_metadata` and `complete: false`, and one
    stream file per stream, to which the writer appends every flush period from now on."""
    if loggers.folder is not None:
        raise RuntimeError(f"the run's loggers already write to {loggers.folder.path}")
    loggers.diagram_timers = compute_timers(diagram)
    loggers.folder = RunFolder(Path(path), loggers.schemas(), run_metadata)
    loggers.flush()  # what was recorded before (an initialized simulator's first samples)
    return loggers.folder.path


def write_run_folder(path: str | Path, loggers: RunLoggers, simulator, run_metadata: dict
                     ) -> Path:
    """Ends the run folder of `simulator`'s run (starts it first when `open_run_folder` was not
    called): records the last samples, appends every stream's last rows and the last compute
    times, converts the streams to Parquet and completes metadata.json with `run_metadata`
    (added to, or replacing, what `open_run_folder` wrote)."""
    path = Path(path)
    if loggers.folder is None:
        open_run_folder(path, loggers, simulator.get_system(), run_metadata)
    elif loggers.folder.path != path:
        raise ValueError(f"the run's loggers write to {loggers.folder.path}, not {path}")
    root_context = simulator.get_context()
    if loggers.imu_sink is not None:
        loggers.imu_sink.ForcedPublish(loggers.imu_sink.GetMyContextFromRoot(root_context))
    loggers.flush()
    loggers.folder.finish(run_metadata)
    loggers.folder = None
    return path


class RunLog:
    """A run folder read back: `run.metadata` (dict) and `run["ground_truth"]` (DataFrame).
    A folder whose run did not finish (`run.complete` false) reads each stream up to its last
    complete batch, with a `RunFolderWarning`; a missing or unreadable metadata.json or stream
    file is a `RunFolderError` (`RunFolderFileMissing` when it is not there) naming the file."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        metadata_file = self.path / "metadata.json"
        if not metadata_file.is_file():
            raise RunFolderFileMissing(f"{self.path} is not a run folder: no metadata.json")
        try:
            self.metadata = json.loads(metadata_file.read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
            raise RunFolderError(f"{metadata_file}: unreadable ({e}); the run folder's "
                                 f"description is damaged") from None
        if not isinstance(self.metadata, dict) or not isinstance(
                self.metadata.get("streams"), dict):
            raise RunFolderError(f"{metadata_file}: no 'streams' table: not the metadata of "
                                 f"a run folder")
        self._frames: dict[str, pd.DataFrame] = {}

    @property
    def streams(self) -> list[str]:
        return list(self.metadata["streams"])

    @property
    def complete(self) -> bool:
        """False when the run died before its end (the folder holds what was flushed)."""
        return bool(self.metadata.get("complete", True))

    def __getitem__(self, stream: str) -> pd.DataFrame:
        if stream not in self.metadata["streams"]:
            raise KeyError(f"{self.path}: no stream '{stream}' (has {self.streams})")
        if stream not in self._frames:
            self._frames[stream] = self._read(stream)
        return self._frames[stream]

    def _read(self, stream: str) -> pd.DataFrame:
        file = self.path / self.metadata["streams"][stream]["file"]
        partial = file.with_suffix(".arrows")
        if file.is_file():
            try:
                return pd.read_parquet(file)
            except (OSError, pa.ArrowException, ValueError) as e:
                raise RunFolderError(f"{file} (stream '{stream}'): damaged, nothing readable "
                                     f"({e})") from None
        if not partial.is_file():
            raise RunFolderFileMissing(f"{file} (stream '{stream}'): missing"
                                       + ("" if self.complete else
                                          f", and no {partial.name} of the unfinished run"))
        return self._read_partial(stream, partial)

    def _read_partial(self, stream: str, partial: Path) -> pd.DataFrame:
        """An Arrow IPC stream up to its last complete batch."""
        batches, problem = [], ""
        try:
            with pa.OSFile(str(partial), "rb") as source:
                reader = pa.ipc.open_stream(source)
                schema = reader.schema
                while True:
                    try:
                        batches.append(reader.read_next_batch())
                    except StopIteration:
                        break
                    except (OSError, pa.ArrowException) as e:
                        problem = f"the file ends cut short or damaged after them ({e})"
                        break
        except (OSError, pa.ArrowException) as e:
            raise RunFolderError(f"{partial} (stream '{stream}'): damaged, nothing readable "
                                 f"({e})") from None
        frame = pa.Table.from_batches(batches, schema).to_pandas()
        if problem or not self.complete:
            until = f" up to t = {frame['time'].iloc[-1]:.2f} s" if len(frame) else ""
            why = problem or "the run did not finish"
            warnings.warn(RunFolderWarning(f"{partial} (stream '{stream}'): read {len(frame)} "
                                           f"rows{until}; {why}"), stacklevel=4)
        return frame

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
