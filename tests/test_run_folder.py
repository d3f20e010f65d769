"""Run folders written while the run goes (diagrams/running/run_log.py): every stream reaches the
disk at least every flush period of simulated time and no sink holds more than one period of rows;
a run killed with SIGKILL leaves a folder that reads back up to its last flush; a damaged or
missing file is an error that names it, a stream cut short gives its rows and a warning."""
import json
import shutil
import signal
import subprocess
import sys
import time
import warnings

import numpy as np
import pandas as pd
import pytest
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from alight.diagrams.onboard.pilot import add_pilot_onboard, pilot_model
from alight.diagrams.running.run_log import (FLUSH_PERIOD, RunFolderError, RunFolderFileMissing,
                                             RunFolderWarning, open_run_folder, read_run,
                                             write_run_folder)
from alight.diagrams.world.sim_vehicle import make_sim_vehicle
from alight.systems.timing import ComputeTimer
from conftest import TAKEOFF, profile

PERIOD = 0.01  # s, the vector streams' sampling period


def read_quietly(path) -> dict[str, pd.DataFrame]:
    """Every stream of a (maybe unfinished) run folder, as a reader would see it now."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RunFolderWarning)
        run = read_run(path)
        return {stream: run[stream] for stream in run.streams}


def hover_flight(vehicle_config):
    builder = DiagramBuilder()
    vehicle = builder.AddNamedSystem("vehicle", make_sim_vehicle(vehicle_config))
    loggers = add_pilot_onboard(builder, vehicle, profile(TAKEOFF + "{duration: 2.0}"),
                                pilot_model(vehicle_config.airframe))
    loggers.timers["probe"] = ComputeTimer()
    diagram = builder.Build()
    return diagram, loggers, Simulator(diagram)


@pytest.fixture(scope="module")
def folders(vehicle_config, tmp_path_factory):
    """(finished folder, the same run's folder as it stood at t = 3.5 s, before its end)."""
    root = tmp_path_factory.mktemp("folders")
    diagram, loggers, simulator = hover_flight(vehicle_config)
    open_run_folder(root / "run", loggers, diagram, {"command": "test"})
    simulator.AdvanceTo(3.5)
    shutil.copytree(root / "run", root / "unfinished")
    simulator.AdvanceTo(5.0)
    write_run_folder(root / "run", loggers, simulator, {"duration": 5.0})
    return root / "run", root / "unfinished"


def test_every_stream_is_on_disk_within_a_flush_period_and_sinks_hold_one_period(
        vehicle_config, tmp_path):
    diagram, loggers, simulator = hover_flight(vehicle_config)
    open_run_folder(tmp_path / "run", loggers, diagram, {"command": "test"})
    run = read_run(tmp_path / "run")
    assert not run.complete and run.metadata["command"] == "test"
    assert set(run.streams) == {"fc_status", "fc_attitude", "range", "ground_truth", "fc_command",
                                "imu", "timing"}
    probe = loggers.timers["probe"]
    recorded, expected_timing, previous_flush = [], [], -1.0
    for t in [0.35, 1.0, 1.42, 2.0, 2.99, 4.25, 6.0]:
        simulator.AdvanceTo(t)
        on_disk = read_quietly(tmp_path / "run")
        flushed = np.floor(t / FLUSH_PERIOD + 1e-9) * FLUSH_PERIOD  # the last flush
        for name, frame in on_disk.items():
            if name == "timing":
                continue
            period = 0.1 if name == "imu" else PERIOD
            # Nothing older than the last flush is missing (a sink recording at the flush
            # instant after the writer sends that row with the next flush), nothing newer is
            # there yet; the rows are every sample, once.
            last = frame["time"].iloc[-1] if len(frame) else -np.inf
            assert last <= flushed + 1e-9 and (last >= flushed - period - 1e-9
                                               or flushed < period), name
            if name != "imu":
                np.testing.assert_allclose(np.diff(frame["time"]), PERIOD, atol=1e-9)
        # Each sink keeps only what came since the last flush, and the timers are emptied.
        for sink, _ in loggers.vector_sinks.values():
            assert sink.pending <= round(FLUSH_PERIOD / PERIOD) + 1
        assert loggers.imu_sink.pending <= round(FLUSH_PERIOD / vehicle_config.imu.period) + 20
        # Compute times go with the next flush after they were measured, and leave the timer.
        if flushed > previous_flush:
            expected_timing, recorded = expected_timing + recorded, []
        previous_flush = flushed
        assert list(on_disk["timing"]["time"]) == expected_timing
        assert len(probe) == len(recorded)
        probe.record(t, "tick", 0.001)
        recorded.append(t)


def test_a_finished_folder_reads_as_parquet_and_holds_what_the_unfinished_one_held(folders):
    finished, unfinished = folders
    run = read_run(finished)
    assert run.complete and run.metadata["duration"] == 5.0 and run.metadata["command"] == "test"
    assert sorted(p.suffix for p in finished.iterdir()) == [".json"] + [".parquet"] * 7
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a finished run reads without a warning
        frames = {stream: run[stream] for stream in run.streams}
    for stream, frame in frames.items():
        assert run.metadata["streams"][stream]["rows"] == len(frame)
    assert frames["ground_truth"]["time"].iloc[-1] == pytest.approx(5.0)
    partial = read_run(unfinished)
    assert not partial.complete
    for stream in ["ground_truth", "fc_status", "fc_command", "imu"]:
        with pytest.warns(RunFolderWarning, match=rf"{stream}\.arrows \(stream '{stream}'\): "
                                                  r"read \d+ rows up to t = 3\.0\d s; the run "
                                                  r"did not finish"):
            head = partial[stream]
        assert len(head) > 0
        pd.testing.assert_frame_equal(head, frames[stream].iloc[:len(head)], check_exact=True)


def test_a_stream_cut_short_reads_up_to_its_last_complete_batch(folders, tmp_path):
    _, unfinished = folders
    shutil.copytree(unfinished, tmp_path / "cut")
    file = tmp_path / "cut" / "ground_truth.arrows"
    whole = read_quietly(unfinished)["ground_truth"]
    file.write_bytes(file.read_bytes()[:-500])  # a batch half written when the power went
    with pytest.warns(RunFolderWarning, match=r"ground_truth\.arrows \(stream 'ground_truth'\): "
                                              r"read 201 rows up to t = 2\.00 s; the file ends "
                                              r"cut short"):
        head = read_run(tmp_path / "cut")["ground_truth"]
    pd.testing.assert_frame_equal(head, whole.iloc[:201], check_exact=True)


def test_damaged_and_missing_files_are_errors_that_name_them(folders, tmp_path):
    finished, _ = folders
    shutil.copytree(finished, tmp_path / "run")
    run_dir = tmp_path / "run"
    damaged = run_dir / "fc_status.parquet"
    data = bytearray(damaged.read_bytes())
    data[-40:] = b"\x00" * 40  # the footer
    damaged.write_bytes(bytes(data))
    (run_dir / "imu.parquet").unlink()
    run = read_run(run_dir)
    with pytest.raises(RunFolderError, match=r"fc_status\.parquet \(stream 'fc_status'\): "
                                             r"damaged"):
        run["fc_status"]
    with pytest.raises(RunFolderFileMissing, match=r"imu\.parquet \(stream 'imu'\): missing"):
        run["imu"]
    assert len(run["ground_truth"]) == 501  # the others still read
    metadata = run_dir / "metadata.json"
    metadata.write_text(metadata.read_text()[:-30])
    with pytest.raises(RunFolderError, match=r"metadata\.json: unreadable"):
        read_run(run_dir)
    metadata.write_text(json.dumps({"seed": 0}))
    with pytest.raises(RunFolderError, match=r"metadata\.json: no 'streams'"):
        read_run(run_dir)
    metadata.unlink()
    with pytest.raises(FileNotFoundError, match="not a run folder: no metadata.json"):
        read_run(run_dir)  # RunFolderFileMissing is a FileNotFoundError too


@pytest.mark.mission
def test_a_landing_killed_with_sigkill_leaves_a_folder_readable_up_to_its_last_flush(tmp_path):
    run_dir = tmp_path / "killed"
    process = subprocess.Popen(
        [sys.executable, "-m", "alight.diagrams.cli", "land", "--seed", "0",
         "--set", "simulator.max_duration: 30", "--run-dir", str(run_dir)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    seen = []  # the newest ground-truth time on disk, each time the test looked
    try:
        deadline = time.monotonic() + 240.0
        while time.monotonic() < deadline and process.poll() is None:
            if (run_dir / "metadata.json").is_file():
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", RunFolderWarning)
                    frame = read_run(run_dir)["ground_truth"]
                if len(frame) and (not seen or frame["time"].iloc[-1] > seen[-1]):
                    seen.append(frame["time"].iloc[-1])
                if seen and seen[-1] >= 4.0:
                    break
            time.sleep(0.02)
        assert process.poll() is None, "the landing ended before it could be killed"
        process.send_signal(signal.SIGKILL)
    finally:
        process.kill()
        process.wait()
    # Seen from outside while it flew: the streams grew flush by flush, not at the end.
    assert len(seen) >= 3 and seen[-1] >= 4.0
    run = read_run(run_dir)
    assert not run.complete and run.metadata["command"] == "land"
    assert (run_dir / "scenario.yaml").is_file()  # the run can be flown again
    for stream in run.streams:
        with pytest.warns(RunFolderWarning, match=rf"stream '{stream}'"):
            frame = run[stream]
        if stream in ("timing", "imu"):
            assert len(frame) > 0 and frame["time"].iloc[-1] >= seen[-1] - FLUSH_PERIOD
            continue
        period = np.diff(frame["time"].to_numpy())
        np.testing.assert_allclose(period, period[0], atol=1e-9)  # every sample, no gap
        # Everything flushed before the kill is there, up to the last flush it saw or later.
        assert frame["time"].iloc[-1] >= seen[-1] - period[0] - 1e-9, stream
