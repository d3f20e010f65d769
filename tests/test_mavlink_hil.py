"""End to end on one machine: `alight hil --mission hover` flies `alight sim-autopilot` over MAVLink
(UDP loopback), both in real time: it takes off, hovers and lands, the mission's own disarm ends the
flight, and every IMU sample of the simulated autopilot crosses the link exactly once.

The onboard side follows the simulated autopilot's clock (`--follow-autopilot-clock`): this test
machine is shared, the vehicle simulation (1.85x real time on a free core) may fall behind the wall
clock, and an open-loop pilot profile squeezed or stretched by that lag would fly another flight.
"""
import subprocess
import sys

import numpy as np

from alight.diagrams.run_log import read_run
from alight.systems.boundary import ActiveMode
from mavlink_fake import SimAutopilotProcess

RATE = 1.0
PROFILE = "hil_hover_profile.yaml"  # 15.6 s: climb to ~1 m, hover, descend, cut thrust


def test_hil_hover_against_the_sim_autopilot_takes_off_hovers_and_lands(tmp_path):
    server = SimAutopilotProcess(tmp_path / "sim-autopilot", realtime_rate=RATE)
    try:
        hil = subprocess.run(
            [sys.executable, "-m", "alight.diagrams.cli", "hil", "--connect", server.url,
             "--mission", "hover", "--profile", PROFILE, "--frames", "none",
             "--realtime-rate", str(RATE), "--follow-autopilot-clock",
             "--run-dir", str(tmp_path / "hil")],
            capture_output=True, text=True, timeout=120)
    finally:
        assert server.stop() == 0, "".join(server.output)
    assert hil.returncode == 0, hil.stdout + hil.stderr
    # The mission landed and disarmed on its own: nothing was left for the final safe command.
    assert "final safe command: disarmed: nothing to do" in hil.stdout, hil.stdout
    sim = read_run(server.run_dir)
    onboard = read_run(tmp_path / "hil")
    gt = sim["ground_truth"]
    t, z, v_z = gt["time"].to_numpy(), gt["p_WB_2"].to_numpy(), gt["v_WB_2"].to_numpy()
    rest = z[0]
    # Took off ...
    assert z.max() - rest > 0.5
    # ... hovered: at least 1 s above 0.3 m with a vertical speed under 0.25 m/s ...
    hovering = (z - rest > 0.3) & (np.abs(v_z) < 0.25)
    assert np.sum(hovering) * np.median(np.diff(t)) > 1.0
    # ... and landed: touchdown slower than 1.5 m/s, at rest on the ground, disarmed.
    airborne = np.flatnonzero(z - rest > 0.05)
    touchdown = airborne[-1] + 1
    assert abs(v_z[touchdown - 5:touchdown + 1]).min() < 1.5
    assert abs(z[-1] - rest) < 0.03 and sim["fc_status"]["armed"].iloc[-1] == 0.0
    # The flight controller followed the onboard commands in OFFBOARD (never its failsafe).
    modes = set(sim["fc_status"]["mode"])
    assert ActiveMode.ATTITUDE_THRUST in modes and ActiveMode.FAILSAFE_DESCENT not in modes
    # The onboard side saw the same: armed, then disarmed, link alive throughout.
    status = onboard["fc_status"]
    assert status["armed"].max() == 1.0 and status["armed"].iloc[-1] == 0.0
    assert status[status["time"] > 1.0]["link_alive"].min() == 1.0
    # Every IMU sample once: after the rate request (first second), the onboard samples are
    # consecutive samples of the simulated IMU (matched by value: float32 on the wire).
    sim_imu, hil_imu = sim["imu"], onboard["imu"]
    columns = ["accel_x", "accel_y", "accel_z", "gyro_x", "gyro_y", "gyro_z"]
    index = {tuple(row): k for k, row in enumerate(sim_imu[columns].to_numpy(np.float32))}
    later = hil_imu[hil_imu["time"] > 1.0]
    matched = [index.get(tuple(row)) for row in later[columns].to_numpy(np.float32)]
    assert None not in matched and len(matched) > 200 * 10
    assert np.all(np.diff(matched) == 1)
    assert np.all(np.diff(hil_imu["time"]) > 0) and np.all(np.diff(hil_imu["seq"]) == 1)
