"""Every notebook under notebooks/ runs; the command line works end to end."""
import os
import subprocess
import sys
from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient

from alight.diagrams.cli import COMMANDS, main
from alight.diagrams.running.run_log import read_run
from alight.diagrams.scenario import load_scenario

NOTEBOOKS = sorted((Path(__file__).resolve().parents[1] / "notebooks").glob("*.ipynb"))


@pytest.mark.mission
@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_executes(path, hover_run, tmp_path, monkeypatch):
    monkeypatch.setenv("ALIGHT_RUN_DIR", str(hover_run.path))
    notebook = nbformat.read(path, as_version=4)
    NotebookClient(notebook, timeout=600, kernel_name="python3",
                   resources={"metadata": {"path": str(tmp_path)}}).execute()
    outputs = [o for c in notebook.cells if c.cell_type == "code" for o in c.get("outputs", [])]
    assert not [o for o in outputs if o.get("output_type") == "error"]
    printed = "".join(o.get("text", "") for o in outputs if o.get("output_type") == "stream")
    assert "skipped" not in printed, printed  # every part ran (../shared/data is there)
    if path.name == "sysid.ipynb":
        # The shared PX4 log barely moves its attitude setpoint: the identification refuses it,
        # naming why, instead of returning a meaningless fit (the notebook's last section).
        assert "refused:" in printed, printed


def test_help_lists_every_command_with_a_description():
    result = subprocess.run([sys.executable, "-m", "alight.diagrams.cli", "--help"],
                            capture_output=True, text=True, check=True)
    for name, text in COMMANDS.items():
        assert name in result.stdout and text.split()[0] in result.stdout


def test_hover_command_writes_a_run_folder_and_a_replay(tmp_path, capsys):
    short = tmp_path / "short.yaml"
    short.write_text("segments:\n"
                     "  - {duration: 0.5, arm: true, vertical_acceleration: -9.81}\n"
                     "  - {duration: 1.0, arm: true, vertical_acceleration: 1.0}\n"
                     "  - {duration: 1.0, arm: true, vertical_acceleration: -1.0}\n")
    replay = tmp_path / "replay.html"
    assert main(["hover", "--profile", str(short), "--run-dir", str(tmp_path / "run"),
                 "--record", str(replay), "--seed", "4", "--wind", "10"]) == 0
    out = capsys.readouterr().out
    assert "max altitude" in out and str(tmp_path / "run") in out
    run = read_run(tmp_path / "run")
    assert run.metadata["seed"] == 4
    scenario = load_scenario(run.path / "scenario.yaml")     # the run folder pins its run
    assert scenario.vehicle.wind.mean_speed == pytest.approx(10 / 3.6)
    assert scenario.random_seed == 4 and scenario.mission.duration == 2.5
    assert set(run.streams) == {"fc_command", "fc_status", "fc_attitude", "range", "ground_truth",
                                "imu", "timing"}
    html = replay.read_text()
    assert html.startswith("<!DOCTYPE html>") or "<html" in html[:200].lower()
    # The scene geometry and the animation are embedded as base64 Meshcat commands.
    assert html.count("data:application/octet-binary;base64") > 20


def test_run_log_reader_refuses_a_folder_that_is_not_a_run(tmp_path):
    with pytest.raises(FileNotFoundError, match="not a run folder"):
        read_run(tmp_path)
