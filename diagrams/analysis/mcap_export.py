"""A run folder as one MCAP file for Foxglove and PlotJuggler (`alight export RUN --mcap`).

Channels (log time = the sample's simulated time in ns; docs/run_folder.md "Export"):
    /<stream>         every stream of the run folder, one JSON message per row with one field per
                      column (JSON schema), for plots (PlotJuggler, Foxglove's Plot panel)
    /poses/<frame>    foxglove.PoseInFrame of each pose the run logged, in frame `world`:
                      `vehicle` and `target` (ground truth), each state estimate stream
                      (`state_estimate`, `vio_estimate`, `bank_estimate`: p_EB, q_EB) and the
                      target EKF's `target_estimate`; rows without a pose (target absent,
                      estimate not valid, not finite) are left out
    /tf/<frame>       foxglove.FrameTransform world -> <frame>, the same samples
    /paths/<frame>    foxglove.PosesInFrame: the whole path once, at its last sample
    /mission          foxglove.Log: the landing mission's mode transitions (landing runs)
    /scene            foxglove.SceneUpdate, once: a box on the `vehicle` frame and the landing
                      platform on the `target` frame (frame-locked: they move with /tf)

The estimator frame E is drawn as W: the estimators start in W (the take-off point surveyed),
so the gap between `/poses/vehicle` and an estimate is the estimate's error. Run folders do not
record camera images (docs/run_folder.md), so no image channel is written.
"""
import dataclasses as dc
import json
from pathlib import Path

import numpy as np
import pandas as pd
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.Log_pb2 import Log
from foxglove_schemas_protobuf.Pose_pb2 import Pose
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from foxglove_schemas_protobuf.PosesInFrame_pb2 import PosesInFrame
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import CompressionType, Writer
from mcap_protobuf.schema import register_schema

from alight.diagrams.running.run_log import RunFolderError, RunLog

WORLD = "world"
# Boxes drawn on the frames in Foxglove's 3D panel: size [m] and colour (r, g, b, a).
SHAPES = {"vehicle": ((0.55, 0.55, 0.15), (0.1, 0.3, 0.9, 1.0)),   # the F550's span
          "target": ((1.5, 1.5, 0.05), (0.9, 0.4, 0.0, 0.8))}     # the platform, DESIGN.md


class ExportError(RunFolderError):
    """A run folder that cannot be exported; the message names the folder and the stream."""


@dc.dataclass(frozen=True)
class PoseTrack:
    """One pose logged by a run: `stream`'s columns `position` (3) and `orientation` (4, w x y
    z), drawn as `frame`; rows count where `present` (a 0/1 column) is set, if given."""
    stream: str
    frame: str
    position: str
    orientation: str
    present: str | None

    def samples(self, run: RunLog) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """time [s], p (n x 3), q (n x 4, w x y z) of the rows that have a pose."""
        rows = run[self.stream]
        try:
            t = rows["time"].to_numpy()
            p = run.field(self.stream, self.position).to_numpy()
            q = run.field(self.stream, self.orientation).to_numpy()
        except KeyError as e:
            raise ExportError(f"{run.path} (stream '{self.stream}'): no column {e} for the "
                              f"pose of '{self.frame}'") from None
        keep = np.isfinite(t) & np.isfinite(p).all(axis=1) & np.isfinite(q).all(axis=1)
        keep &= np.linalg.norm(q, axis=1) > 0.5
        if self.present is not None:
            keep &= rows[self.present].to_numpy() > 0.5
        return t[keep], p[keep], q[keep]


def pose_tracks(run: RunLog) -> list[PoseTrack]:
    """The poses `run` logged: the vehicle and target of `ground_truth`, every state estimate
    (fields p_EB, q_EB) and the target estimate (p_WT, q_WT of a stream with `valid`)."""
    tracks = []
    for stream, entry in run.metadata["streams"].items():
        fields = entry.get("fields", {})
        if stream == "ground_truth":
            tracks.append(PoseTrack(stream, "vehicle", "p_WB", "q_WB", None))
            if "p_WT" in fields:
                tracks.append(PoseTrack(stream, "target", "p_WT", "q_WT", "target_present"))
        elif "p_EB" in fields and "q_EB" in fields:
            tracks.append(PoseTrack(stream, stream, "p_EB", "q_EB", _valid(fields)))
        elif "p_WT" in fields and "q_WT" in fields:
            tracks.append(PoseTrack(stream, stream, "p_WT", "q_WT", _valid(fields)))
    return tracks


def _valid(fields: dict) -> str | None:
    return "valid" if "valid" in fields else None


def export_mcap(run_dir: str | Path, out: str | Path | None = None) -> Path:
    """Writes the run folder `run_dir` as an MCAP file (default `<run_dir>/<name>.mcap`) and
    returns its path. Every stream is read first: a missing or damaged one is an error naming
    it (RunFolderError), and no file is left behind."""
    run = RunLog(run_dir)
    out = Path(out) if out is not None else run.path / f"{run.path.name}.mcap"
    frames = {stream: run[stream] for stream in run.streams}  # raises naming the stream
    tracks = pose_tracks(run)
    samples = {track: track.samples(run) for track in tracks}
    transitions = _mission_transitions(run)
    partial = out.with_name(out.name + ".part")
    out.parent.mkdir(parents=True, exist_ok=True)
    try:
        with partial.open("wb") as stream:
            mcap = _McapOut(stream)
            mcap.writer.add_metadata("alight", _run_metadata(run))
            for name, frame in frames.items():
                _write_table(mcap, name, frame)
            for track in tracks:
                _write_track(mcap, track, *samples[track])
            _write_log(mcap, "/mission", transitions)
            _write_scene(mcap, [track.frame for track in tracks if samples[track][0].size])
            mcap.writer.finish()
        partial.replace(out)
    finally:
        partial.unlink(missing_ok=True)
    return out


class _McapOut:
    """An MCAP writer (zstd chunks) with each protobuf schema registered once."""

    def __init__(self, stream):
        self.writer = Writer(stream, compression=CompressionType.ZSTD)
        self.writer.start(profile="", library="alight")
        self._schemas: dict[type, int] = {}

    def protobuf_channel(self, topic: str, message_class) -> int:
        if message_class not in self._schemas:
            self._schemas[message_class] = register_schema(self.writer, message_class)
        return self.writer.register_channel(topic, MessageEncoding.Protobuf,
                                            self._schemas[message_class])

    def add(self, channel: int, t: float, data: bytes, sequence: int = 0) -> None:
        """A message logged (and published) at simulated time `t` [s]."""
        self.writer.add_message(channel, log_time=_ns(t), data=data, publish_time=_ns(t),
                                sequence=sequence)


def _ns(t: float) -> int:
    return int(round(t * 1e9))


def _run_metadata(run: RunLog) -> dict[str, str]:
    keys = ("command", "seed", "scenario_name", "estimator", "controller", "duration", "created",
            "complete", "landed")
    return {key: str(run.metadata[key]) for key in keys if key in run.metadata}


def _json_type(column: pd.Series) -> str:
    if pd.api.types.is_bool_dtype(column):
        return "boolean"
    if pd.api.types.is_integer_dtype(column):
        return "integer"
    if pd.api.types.is_numeric_dtype(column):
        return "number"
    return "string"


def _write_table(out: "_McapOut", name: str, frame: pd.DataFrame) -> None:
    """One JSON message per row of stream `name` on /<name>: one field per column (a value
    that is not finite is null, which JSON has, not NaN)."""
    properties = {column: {"type": [_json_type(frame[column]), "null"]}
                  for column in frame.columns}
    schema = out.writer.register_schema(
        name=f"alight.{name}", encoding=SchemaEncoding.JSONSchema,
        data=json.dumps({"type": "object", "properties": properties}).encode())
    channel = out.writer.register_channel(f"/{name}", MessageEncoding.JSON, schema)
    columns = [_json_values(frame[column]) for column in frame.columns]
    times = frame["time"].to_numpy() if "time" in frame else np.zeros(len(frame))
    for sequence, (t, row) in enumerate(zip(times, zip(*columns))):
        out.add(channel, t, json.dumps(dict(zip(frame.columns, row)), allow_nan=False).encode(),
                sequence)


def _json_values(column: pd.Series) -> list:
    """The column as Python values; null where a number is not finite or a value missing."""
    if pd.api.types.is_float_dtype(column):
        values = column.to_numpy()
        return [float(v) if np.isfinite(v) else None for v in values]
    return [None if pd.isna(v) else v for v in column.tolist()]


def _pose(p: np.ndarray, q: np.ndarray) -> Pose:
    pose = Pose()
    pose.position.x, pose.position.y, pose.position.z = map(float, p)
    pose.orientation.w, pose.orientation.x, pose.orientation.y, pose.orientation.z = map(float, q)
    return pose


def _write_track(out: _McapOut, track: PoseTrack, t: np.ndarray, p: np.ndarray,
                 q: np.ndarray) -> None:
    """/poses/<frame> (PoseInFrame), /tf/<frame> (FrameTransform) per sample; /paths/<frame>
    (PosesInFrame) once, at the last sample."""
    pose_channel = out.protobuf_channel(f"/poses/{track.frame}", PoseInFrame)
    tf_channel = out.protobuf_channel(f"/tf/{track.frame}", FrameTransform)
    for k in range(len(t)):
        pose = _pose(p[k], q[k])
        in_frame = PoseInFrame(frame_id=WORLD, pose=pose)
        in_frame.timestamp.FromNanoseconds(_ns(t[k]))
        transform = FrameTransform(parent_frame_id=WORLD, child_frame_id=track.frame,
                                   translation=pose.position, rotation=pose.orientation)
        transform.timestamp.FromNanoseconds(_ns(t[k]))
        out.add(pose_channel, t[k], in_frame.SerializeToString(), k)
        out.add(tf_channel, t[k], transform.SerializeToString(), k)
    if len(t):
        path = PosesInFrame(frame_id=WORLD, poses=[_pose(pk, qk) for pk, qk in zip(p, q)])
        path.timestamp.FromNanoseconds(_ns(t[-1]))
        out.add(out.protobuf_channel(f"/paths/{track.frame}", PosesInFrame), t[-1],
                path.SerializeToString())


def _mission_transitions(run: RunLog) -> list[tuple[float, str]]:
    """(time [s], text) of each landing mission mode transition; none without `mission_status`."""
    if "mission_status" not in run.streams:
        return []
    from alight.diagrams.analysis.landing import mission_transitions
    try:
        return [(at, f"{mode.name} ({reason.name.lower().replace('_', ' ')})")
                for at, mode, reason in mission_transitions(run)]
    except (KeyError, ValueError) as e:
        raise ExportError(f"{run.path} (stream 'mission_status'): not a landing mission's "
                          f"status ({e})") from None


def _write_log(out: _McapOut, topic: str, entries: list[tuple[float, str]]) -> None:
    if not entries:
        return
    channel = out.protobuf_channel(topic, Log)
    for sequence, (at, text) in enumerate(entries):
        message = Log(level=Log.INFO, message=text, name="mission")
        message.timestamp.FromNanoseconds(_ns(at))
        out.add(channel, at, message.SerializeToString(), sequence)


def _write_scene(out: _McapOut, frames: list[str]) -> None:
    """/scene: one SceneUpdate at t = 0 with a frame-locked box per frame of SHAPES present."""
    update = SceneUpdate()
    for frame in frames:
        if frame not in SHAPES:
            continue
        size, color = SHAPES[frame]
        entity = update.entities.add(frame_id=frame, id=frame, frame_locked=True)
        cube = entity.cubes.add()
        cube.pose.orientation.w = 1.0
        cube.size.x, cube.size.y, cube.size.z = size
        cube.color.r, cube.color.g, cube.color.b, cube.color.a = color
    if update.entities:
        out.add(out.protobuf_channel("/scene", SceneUpdate), 0.0, update.SerializeToString())
