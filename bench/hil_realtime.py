"""`alight hil --mission fly|land|hover` against `alight sim-autopilot`, both in real time over UDP
loopback, as tests/test_mavlink_hil.py runs them: does each side keep rate 1, and how much CPU
does each need per simulated second?

Prints the machine's load average before and after, and each side's real-time report: simulated
and wall time, rate, overruns (ticks ending > 20 ms behind the wall clock), max lag and CPU s per
simulated s (all threads of the process). `--no-follow` runs the onboard side on the wall clock
alone (the default follows the autopilot's clock, as the tests do: a side that falls behind
slows the other, so rate < 1 means real time was not held). `--autopilot-prefix` /
`--hil-prefix` wrap a side's command, e.g. with a profiler:

    python bench/hil_realtime.py --mission fly [--repeats 2]
    python bench/hil_realtime.py --mission land
    python bench/hil_realtime.py --mission fly \
        --autopilot-prefix "py-spy record -r 250 -f raw -o /tmp/ap.txt --"
"""
import argparse
import os
import re
import shlex
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

MISSIONS = {
    "hover": (("--profile", "hil_hover_profile.yaml", "--frames", "none"), ("--frames", "none")),
    "fly": (("--waypoints", "0,0,2; 3,0,2"), ()),
    "land": (("--scenario", "scenario_field_hil.yaml", "--target-speed", "2"),
             ("--scenario", "scenario_field_hil.yaml", "--target-speed", "2", "--seed", "0")),
}
_REPORT = re.compile(r"ran ([\d.]+) s in ([\d.]+) s wall \(rate ([\d.]+)\), (\d+) overruns of "
                     r"(\d+) ticks, max lag ([\d.]+) ms.*?(?:, ([\d.]+) CPU s per simulated s)?$")


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Side:
    """One process, its output collected; `ready` set on the line that contains `marker`."""

    def __init__(self, command: list[str], marker: str):
        self.process = subprocess.Popen(command, stdout=subprocess.PIPE,
                                        stderr=subprocess.STDOUT, text=True)
        self.lines: list[str] = []
        self.ready = threading.Event()
        self._marker = marker
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self):
        for line in self.process.stdout:
            self.lines.append(line)
            if self._marker in line:
                self.ready.set()

    def stop(self, timeout: float = 60.0) -> int:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
        try:
            status = self.process.wait(timeout)
        except subprocess.TimeoutExpired:
            self.process.kill()
            status = self.process.wait()
        self._reader.join(5.0)
        return status

    def report(self) -> str:
        """The real-time report's first line."""
        for line in reversed(self.lines):
            if _REPORT.search(line.strip()):
                return _REPORT.search(line.strip()).group(0)
        return "no report:\n" + "".join(self.lines[-20:])


def cli(prefix: str) -> list[str]:
    return [*shlex.split(prefix), sys.executable, "-m", "alight.diagrams.cli"]


def run_pair(mission: str, follow: bool, autopilot_prefix: str, hil_prefix: str,
             duration: float, folder: Path) -> tuple[int, Side, Side]:
    hil_args, autopilot_args = MISSIONS[mission]
    port = free_udp_port()
    hil = Side([*cli(hil_prefix), "hil", "--connect", f"udp:127.0.0.1:{port}", "--wait", "60",
                "--mission", mission, *hil_args, *(["--follow-autopilot-clock"] if follow else ["--no-follow-autopilot-clock"]),
                "--run-dir", str(folder / "hil")], "waiting for the autopilot")
    if not hil.ready.wait(90):
        hil.stop()
        raise RuntimeError("alight hil did not start:\n" + "".join(hil.lines))
    autopilot = Side([*cli(autopilot_prefix), "sim-autopilot", "--listen",
                      f"udp:127.0.0.1:{port}", "--duration", str(duration), *autopilot_args,
                      "--run-dir", str(folder / "sim-autopilot")], "sim-autopilot: ready")
    try:
        status = hil.process.wait(duration + 120)
    finally:
        hil.stop()
        autopilot.stop()
    return status, hil, autopilot


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mission", choices=sorted(MISSIONS), default="fly")
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--no-follow", action="store_true",
                        help="onboard side on the wall clock alone")
    parser.add_argument("--duration", type=float, default=60.0,
                        help="s, the simulated autopilot's limit (the mission ends the run)")
    parser.add_argument("--autopilot-prefix", default="", help="wraps the autopilot's command")
    parser.add_argument("--hil-prefix", default="", help="wraps the hil command")
    args = parser.parse_args()
    print(f"machine: {os.cpu_count()} cores; mission {args.mission}, onboard "
          f"{'on the wall clock' if args.no_follow else 'following the autopilot clock'}")
    for k in range(args.repeats):
        load = os.getloadavg()[0]
        start = time.monotonic()
        with tempfile.TemporaryDirectory() as folder:
            status, hil, autopilot = run_pair(args.mission, not args.no_follow,
                                              args.autopilot_prefix, args.hil_prefix,
                                              args.duration, Path(folder))
        print(f"run {k + 1}: exit {status}, {time.monotonic() - start:.0f} s wall, load average "
              f"{load:.2f} before, {os.getloadavg()[0]:.2f} after")
        print(f"  onboard (hil):  {hil.report()}")
        print(f"  sim-autopilot:  {autopilot.report()}")
        if status != 0:
            print("".join(hil.lines[-30:]))


if __name__ == "__main__":
    main()
