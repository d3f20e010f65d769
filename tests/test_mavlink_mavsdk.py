"""Third-party conformance: the `mavsdk` Python package (4.x: MAVSDK's C++ library in-process)
flies `alight sim-autopilot` as it would fly PX4. It discovers a PX4 autopilot, reads attitude and
IMU telemetry, is refused an arm with a high thrust setpoint, arms and starts OFFBOARD with attitude
setpoints, rolls the vehicle 10 degrees right (checked in the simulation's ground truth, which also
checks the frame conversions against an independent encoder) and lands with the land action."""

import numpy as np
import pytest
from mavsdk import Autopilot, ComponentType, Configuration, ConnectionResult, Mavsdk
from mavsdk.plugins.action import Action, ActionError
from mavsdk.plugins.offboard import Attitude, Offboard
from mavsdk.plugins.telemetry import FlightMode, Telemetry

from alight.diagrams.running.run_log import read_run
from alight.systems.rotations import rotation_matrix
from mavlink_fake import SimAutopilotProcess, wait_for, realtime

pytestmark = pytest.mark.mission



@realtime
def test_mavsdk_reads_telemetry_arms_flies_offboard_attitude_and_lands(tmp_path):
    server = SimAutopilotProcess(tmp_path / "sim-autopilot")
    mavsdk = Mavsdk(Configuration.create_with_component_type(ComponentType.COMPANION_COMPUTER))
    received = {"attitude": [], "imu": []}
    try:
        assert mavsdk.add_any_connection(f"udpout://127.0.0.1:{server.port}") == \
            ConnectionResult.SUCCESS
        system = mavsdk.first_autopilot(15.0)
        assert system is not None and system.autopilot_type() == Autopilot.PX4
        telemetry, action, offboard = Telemetry(system), Action(system), Offboard(system)
        telemetry.subscribe_attitude_quaternion(lambda q, _: received["attitude"].append(q))
        telemetry.subscribe_imu(lambda imu, _: received["imu"].append(imu))

        def sim_time():  # the autopilot's clock: the simulation may run behind the wall clock
            return received["attitude"][-1].timestamp_us * 1e-6 if received["attitude"] else 0.0

        def sleep_sim(duration):
            start = sim_time()
            wait_for(lambda: sim_time() >= start + duration, 30.0, f"{duration} s simulated")
        wait_for(lambda: received["attitude"], 10.0, "attitude telemetry")
        sleep_sim(2.0)
        # Telemetry at the autopilot's default rates (50 Hz each), level and at rest.
        for stream in ("attitude", "imu"):
            stamps = np.array([m.timestamp_us for m in received[stream]]) * 1e-6
            assert len(stamps) > 40 and (len(stamps) - 1) / np.ptp(stamps) > 45.0
        q = received["attitude"][-1]
        assert abs(q.w) > 0.999
        down = np.mean([imu.acceleration_frd.down_m_s2 for imu in received["imu"][-40:]])
        assert down == pytest.approx(-9.81, abs=0.15)  # specific force points up (mean of 40)
        assert telemetry.flight_mode() == FlightMode.HOLD and not telemetry.armed()

        offboard.set_attitude(Attitude(0.0, 0.0, 0.0, 0.5))
        offboard.start()
        with pytest.raises(ActionError):  # PX4: thrust setpoint above the arming limit
            action.arm()
        offboard.set_attitude(Attitude(0.0, 0.0, 0.0, 0.1))
        sleep_sim(0.2)
        action.arm()
        wait_for(lambda: telemetry.armed() and telemetry.flight_mode() == FlightMode.OFFBOARD,
                 10.0, "armed in OFFBOARD")
        offboard.set_attitude(Attitude(0.0, 0.0, 0.0, 0.8))
        wait_for(telemetry.in_air, 10.0, "in the air")
        sleep_sim(1.0)
        offboard.set_attitude(Attitude(10.0, 0.0, 0.0, 0.68))  # roll right, FRD/NED
        sleep_sim(1.0)
        roll_seen = np.degrees(2 * np.arctan2(received["attitude"][-1].x,
                                              received["attitude"][-1].w))
        offboard.set_attitude(Attitude(0.0, 0.0, 0.0, 0.64))
        sleep_sim(0.5)
        action.land()
        wait_for(lambda: not telemetry.armed(), 60.0, "landed and disarmed")
    finally:
        mavsdk.destroy()
        assert server.stop() == 0, "".join(server.output)
    assert roll_seen == pytest.approx(10.0, abs=2.0)
    gt = read_run(server.run_dir)["ground_truth"]
    q_WB = gt[["q_WB_0", "q_WB_1", "q_WB_2", "q_WB_3"]].to_numpy()
    # Right wing down in FRD is y_B (left) up in W: the z_W component of y_B is sin(roll).
    y_B_up = np.array([rotation_matrix(q)[2, 1] for q in q_WB])
    assert np.degrees(np.arcsin(y_B_up.max())) == pytest.approx(10.0, abs=2.0)
    z = gt["p_WB_2"].to_numpy()
    assert z.max() - z[0] > 0.5 and abs(z[-1] - z[0]) < 0.05
