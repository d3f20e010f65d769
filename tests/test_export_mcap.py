"""`alight export RUN --mcap`: the first 6 s of the field landing mission written as MCAP and read
back with the `mcap` library: channels, schemas, message counts equal to the streams' rows, log
times the simulated times, poses decoded equal to the logged ones; a damaged or missing stream is
an error naming it, with no file left behind."""
import json
import shutil

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from alight.diagrams.analysis.landing import mission_transitions
from alight.diagrams.analysis.mcap_export import export_mcap
from alight.diagrams.cli import main
from alight.diagrams.running.run_log import RunFolderError, RunFolderFileMissing, read_run

DURATION = 6.0  # s: taking off, the car driving, the state estimate and the mission running


@pytest.fixture(scope="module")
def landing_run(tmp_path_factory):
    from alight.diagrams.running.runner import run
    from alight.diagrams.scenario import load_scenario
    return run(load_scenario("field"), run_dir=tmp_path_factory.mktemp("runs") / "land",
               command="land", duration=DURATION)


@pytest.fixture(scope="module")
def exported(landing_run, tmp_path_factory):
    out = tmp_path_factory.mktemp("mcap") / "land.mcap"
    assert main(["export", str(landing_run.path), "--mcap", str(out)]) == 0
    with out.open("rb") as stream:
        reader = make_reader(stream, validate_crcs=True)
        summary = reader.get_summary()
        protobuf, decoders, messages = DecoderFactory(), {}, {}
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            if channel.message_encoding == "json":
                decoded = json.loads(message.data)
            else:
                if schema.id not in decoders:
                    decoders[schema.id] = protobuf.decoder_for(channel.message_encoding, schema)
                decoded = decoders[schema.id](message.data)
            messages.setdefault(channel.topic, []).append((message, decoded))
    channels = {channel.topic: summary.schemas[channel.schema_id]
                for channel in summary.channels.values()}
    return channels, messages


def test_every_stream_is_a_json_channel_with_one_message_per_row(landing_run, exported):
    channels, messages = exported
    assert len(landing_run.streams) == 17   # the landing's 15, the VIO's odometry and estimate
    assert {"vio_odometry", "vio_estimate"} <= set(landing_run.streams)
    for stream in landing_run.streams:
        rows = landing_run[stream]
        schema = channels[f"/{stream}"]
        assert (schema.name, schema.encoding) == (f"alight.{stream}", "jsonschema")
        assert set(json.loads(schema.data)["properties"]) == set(rows.columns)
        assert len(messages[f"/{stream}"]) == len(rows), stream
        times = [message.log_time for message, _ in messages[f"/{stream}"]]
        np.testing.assert_array_equal(times, np.round(rows["time"].to_numpy() * 1e9))
    # A row read back equals the stream's row (NaN, which JSON lacks, as null).
    message, decoded = messages["/mission_status"][-1]
    last = landing_run["mission_status"].iloc[-1]
    assert decoded["mode"] == last["mode"] == 1.0  # still taking off at 6 s
    assert decoded["first_detection"] is None and np.isnan(last["first_detection"])


def test_poses_and_transforms_of_vehicle_target_and_estimate(landing_run, exported):
    channels, messages = exported
    truth = landing_run["ground_truth"]
    estimate = landing_run["state_estimate"]
    valid = int((estimate["valid"] > 0.5).sum())
    assert 0 < valid < len(estimate)  # not valid before the first estimate
    expected = {"vehicle": len(truth), "target": int((truth["target_present"] > 0.5).sum()),
                "state_estimate": valid, "target_estimate": 0}  # no detection yet
    assert expected["target"] == len(truth)
    for frame, count in expected.items():
        assert channels[f"/poses/{frame}"].name == "foxglove.PoseInFrame"
        assert channels[f"/tf/{frame}"].name == "foxglove.FrameTransform"
        assert len(messages.get(f"/poses/{frame}", [])) == count, frame
        assert len(messages.get(f"/tf/{frame}", [])) == count, frame
        assert len(messages.get(f"/paths/{frame}", [])) == (1 if count else 0), frame
    k = 450  # 4.5 s: climbing
    message, pose = messages["/poses/vehicle"][k]
    assert message.log_time == round(truth["time"].iloc[k] * 1e9)
    assert pose.frame_id == "world"
    p_WB = landing_run.field("ground_truth", "p_WB").iloc[k].to_numpy()
    q_WB = landing_run.field("ground_truth", "q_WB").iloc[k].to_numpy()
    assert p_WB[2] > 1.0
    np.testing.assert_array_equal([pose.pose.position.x, pose.pose.position.y,
                                   pose.pose.position.z], p_WB)
    orientation = pose.pose.orientation
    np.testing.assert_array_equal([orientation.w, orientation.x, orientation.y, orientation.z],
                                  q_WB)
    _, transform = messages["/tf/target"][k]
    assert (transform.parent_frame_id, transform.child_frame_id) == ("world", "target")
    assert transform.translation.x == truth["p_WT_0"].iloc[k]
    _, path = messages["/paths/vehicle"][0]
    assert len(path.poses) == len(truth)
    assert channels["/scene"].name == "foxglove.SceneUpdate"
    [(_, scene)] = messages["/scene"]
    assert [(e.frame_id, e.frame_locked) for e in scene.entities] == [("vehicle", True),
                                                                     ("target", True)]
    assert scene.entities[1].cubes[0].size.x == 1.5  # the landing platform


def test_mission_modes_are_log_messages(landing_run, exported):
    channels, messages = exported
    assert channels["/mission"].name == "foxglove.Log"
    flown = mission_transitions(landing_run)
    assert [m.log_time for m, _ in messages["/mission"]] == [round(t * 1e9) for t, _, _ in flown]
    assert [log.message.split()[0] for _, log in messages["/mission"]] == [
        mode.name for _, mode, _ in flown] == ["TAKING_OFF"]


def test_the_default_file_is_in_the_run_folder(landing_run, tmp_path):
    run_dir = shutil.copytree(landing_run.path, tmp_path / "land")
    assert main(["export", str(run_dir), "--mcap"]) == 0
    assert (run_dir / "land.mcap").is_file()
    assert not list(run_dir.glob("*.part"))
    assert read_run(run_dir)["imu"].shape == landing_run["imu"].shape


def test_a_damaged_or_missing_stream_is_an_error_naming_it(landing_run, tmp_path, capsys):
    run_dir = shutil.copytree(landing_run.path, tmp_path / "land")
    (run_dir / "target_estimate.parquet").write_bytes(b"PAR1 cut short")
    out = tmp_path / "out.mcap"
    with pytest.raises(RunFolderError, match=r"target_estimate\.parquet \(stream "
                                             r"'target_estimate'\): damaged"):
        export_mcap(run_dir, out)
    assert not out.exists() and not list(tmp_path.glob("*.part"))
    assert main(["export", str(run_dir), "--mcap", str(out)]) == 1
    assert "target_estimate" in capsys.readouterr().err
    (run_dir / "target_estimate.parquet").unlink()
    with pytest.raises(RunFolderFileMissing, match=r"target_estimate\.parquet \(stream "
                                                   r"'target_estimate'\): missing"):
        export_mcap(run_dir, out)
    assert not out.exists()


def test_an_unfinished_run_exports_what_was_flushed(landing_run, tmp_path):
    """A run that died: its streams only as Arrow streams (cut to 3 s), metadata incomplete."""
    import pyarrow as pa
    import pyarrow.parquet as pq
    run_dir = shutil.copytree(landing_run.path, tmp_path / "land")
    metadata = json.loads((run_dir / "metadata.json").read_text())
    metadata["complete"] = False
    (run_dir / "metadata.json").write_text(json.dumps(metadata))
    for parquet in run_dir.glob("*.parquet"):
        table = pq.read_table(parquet)
        table = table.filter(pa.compute.less_equal(table["time"], 3.0))
        with pa.OSFile(str(parquet.with_suffix(".arrows")), "wb") as sink:
            with pa.ipc.new_stream(sink, table.schema) as writer:
                writer.write_table(table)
        parquet.unlink()
    with pytest.warns(UserWarning, match="the run did not finish"):
        out = export_mcap(run_dir)
    with out.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    by_topic = {summary.channels[channel].topic: count for channel, count
                in summary.statistics.channel_message_counts.items()}
    truth = landing_run["ground_truth"]
    assert by_topic["/ground_truth"] == by_topic["/poses/vehicle"] == int(
        (truth["time"] <= 3.0).sum()) == 301
