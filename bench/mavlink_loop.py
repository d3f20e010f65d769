"""The MAVLink loop over UDP loopback: `alight sim-autopilot` in its own process, the MAVLink
vehicle diagram in this one, both in real time.

The onboard "controller" echoes the newest IMU sample's gyroscope as its body-rate setpoint
(rates+thrust, thrust 0, never armed); the simulated autopilot recognises its own sample in the
SET_ATTITUDE_TARGET that comes back. Printed, from the autopilot's side:
- the setpoint stream: rate held (mean) and jitter of the arrival intervals (std, p99, max);
- round trip: from a HIGHRES_IMU leaving the simulated autopilot to the first setpoint computed
  from it arriving back: median, p99, max. It spans the link's reader, the `imu` port's 2 ms
  polling, the command sender's 10 ms stream tick (the controller here is direct feedthrough) and
  loopback UDP both ways;
and, as a reference measured in this process, the bare round trip of a MAVLink frame over loopback
UDP between two pymavlink endpoints (encode, send, parse, answer, parse), with the ratio.

    python bench/mavlink_loop.py [--duration 20] [--command-period 0.01]
"""
import argparse
import dataclasses as dc
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.systems.framework import DiagramBuilder, LeafSystem
from pymavlink import mavutil

from alight.hw.link import MavlinkLink
from alight.hw.mavlink_vehicle import load_mavlink_vehicle_params, make_mavlink_vehicle
from alight.hw.realtime import WallClock, run_realtime
from alight.systems.boundary import FC_COMMAND, CommandMode, ImuSamples


class GyroEcho(LeafSystem):
    """Input `imu`; output `fc_command`: rates+thrust with w_D = the newest gyro sample, thrust 0,
    disarmed, stamped now (direct feedthrough: computed when the command sender samples it)."""

    def __init__(self):
        super().__init__()
        self._imu = self.DeclareAbstractInputPort("imu", AbstractValue.Make(ImuSamples.empty()))
        self.DeclareVectorOutputPort("fc_command", FC_COMMAND.size, self._calc)

    def _calc(self, context, output):
        samples = self._imu.Eval(context)
        w_D = samples.gyro[-1] if len(samples) else np.zeros(3)
        output.SetFromVector(FC_COMMAND.pack(stamp=context.get_time(),
                                             mode=CommandMode.RATES_THRUST, q_WD=[1, 0, 0, 0],
                                             w_D=w_D, thrust=0.0, arm=0.0))


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_sim_autopilot(port: int, duration: float, stats: Path, run_dir: Path):
    process = subprocess.Popen(
        [sys.executable, "-m", "alight.diagrams.cli", "sim-autopilot", "--listen",
         f"udp:127.0.0.1:{port}", "--duration", str(duration), "--frames", "none",
         "--stats", str(stats), "--run-dir", str(run_dir)],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    for line in process.stdout:
        if line.startswith("sim-autopilot: ready"):
            break
    threading.Thread(target=lambda: [None for _ in process.stdout], daemon=True).start()
    return process


def fly_echo(port: int, duration: float, command_period: float):
    params = load_mavlink_vehicle_params()
    params = dc.replace(params, command_period=command_period)
    link = MavlinkLink.open(f"udp:127.0.0.1:{port}", params.link, WallClock())
    try:
        link.wait_for_autopilot(30.0)
        rates = link.request_message_rates()
        builder = DiagramBuilder()
        vehicle = builder.AddNamedSystem("vehicle", make_mavlink_vehicle(link, params))
        echo = builder.AddNamedSystem("echo", GyroEcho())
        builder.Connect(vehicle.GetOutputPort("imu"), echo.get_input_port())
        builder.Connect(echo.get_output_port(), vehicle.GetInputPort("fc_command"))
        _, report = run_realtime(builder.Build(), duration, link.clock,
                                 safe_stop=link.safe_stop)
        return report, rates, link.counters_snapshot()
    finally:
        link.close()


def loopback_reference(count: int = 2000) -> np.ndarray:
    """Round trips [s] of a HEARTBEAT between two pymavlink endpoints over loopback UDP."""
    port = free_udp_port()
    server = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=1)
    client = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=2)
    running = True

    def echo():
        while running:
            message = server.recv_match(type="HEARTBEAT", blocking=True, timeout=0.2)
            if message is not None:
                server.mav.heartbeat_send(message.type, message.autopilot, 0,
                                          message.custom_mode, 0)
    thread = threading.Thread(target=echo, daemon=True)
    thread.start()
    trips = []
    for k in range(count):
        start = time.perf_counter()
        client.mav.heartbeat_send(6, 8, 0, k, 0)
        reply = None
        while reply is None or reply.custom_mode != k:
            reply = client.recv_match(type="HEARTBEAT", blocking=True, timeout=1.0)
            if reply is None:
                break
        if reply is not None:
            trips.append(time.perf_counter() - start)
    running = False
    thread.join()
    server.close()
    client.close()
    return np.array(trips)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=20.0, help="s of echo flight")
    parser.add_argument("--command-period", type=float, default=0.01, help="s, setpoint stream")
    args = parser.parse_args()
    port = free_udp_port()
    with tempfile.TemporaryDirectory() as folder:
        stats_file = Path(folder) / "stats.json"
        process = start_sim_autopilot(port, args.duration + 60.0, stats_file,
                                      Path(folder) / "run")
        try:
            report, rates, counters = fly_echo(port, args.duration, args.command_period)
        finally:
            process.send_signal(signal.SIGINT)
            process.wait(60)
        stats = json.loads(stats_file.read_text())
    reference = loopback_reference()
    ms = 1e3
    print(f"machine: {os.cpu_count()} cores, load average {os.getloadavg()[0]:.2f} at the end")
    print(f"companion: {'; '.join(report.lines())}")
    sim = stats["realtime"]
    print(f"sim-autopilot: ran {sim['sim_time']:.1f} s in {sim['wall_time']:.1f} s wall, "
          f"{sim['overruns']} overruns of {sim['ticks']} ticks, max lag "
          f"{ms * sim['max_lag']:.0f} ms")
    print(f"message rates requested: {rates}")
    print(f"link: {counters.messages} messages in, {counters.malformed} malformed, "
          f"{counters.out_of_order} out of order, {counters.lost} lost")
    print(f"setpoint stream ({1 / args.command_period:.0f} Hz asked): {stats['setpoints']} "
          f"setpoints, {stats['setpoint_rate']:.1f} Hz held; interval mean "
          f"{ms * stats['interval_mean']:.2f} ms, std {ms * stats['interval_std']:.2f} ms, p99 "
          f"{ms * stats['interval_p99']:.2f} ms, max {ms * stats['interval_max']:.2f} ms")
    print(f"round trip IMU out -> command back ({stats.get('round_trips', 0)} samples): median "
          f"{ms * stats['round_trip_median']:.2f} ms, p99 {ms * stats['round_trip_p99']:.2f} ms, "
          f"max {ms * stats['round_trip_max']:.2f} ms")
    print(f"reference, bare pymavlink loopback round trip ({len(reference)}): median "
          f"{ms * np.median(reference):.3f} ms, p99 {ms * np.percentile(reference, 99):.3f} ms; "
          f"loop median / reference median = "
          f"{stats['round_trip_median'] / np.median(reference):.0f}x")


if __name__ == "__main__":
    main()
