"""The real-time runner: advances a diagram against the wall clock (Drake `Simulator` with a target
real-time rate of 1), reports overruns, and stops cleanly on Ctrl-C or SIGTERM, always finishing
with the vehicle's final safe command (disarm on the ground, failsafe descent in the air).

A run that cannot keep real time says so once per `warn_period` of wall time, with the rate it
achieved over that period (simulated s per wall s) and how far behind it is, instead of lines for
single late ticks.
"""
import dataclasses as dc
import logging
import math
import signal
import threading
import time
from typing import Callable

from pydrake.common import RandomGenerator
from pydrake.systems.analysis import Simulator

LOG = logging.getLogger("alight.hw")


class WallClock:
    """Onboard time: seconds of `time.monotonic()` since `restart()`, times `rate` (1 on a vehicle;
    below 1 runs a whole HIL setup slowed down, on a machine too loaded for real time). The runner
    restarts it when the simulation starts, so that context time and this clock agree while the
    run keeps up. `scaled_ns()` runs at the same rate without the epoch (TIMESYNC uses it, so a
    restart does not invalidate the clock offset)."""

    def __init__(self, rate: float = 1.0):
        if not (math.isfinite(rate) and 0.0 < rate <= 1.0):
            raise ValueError(f"real-time rate must be in (0, 1], not {rate}")
        self.rate = float(rate)
        self.epoch = time.monotonic()

    def restart(self) -> None:
        self.epoch = time.monotonic()

    def now(self) -> float:
        return (time.monotonic() - self.epoch) * self.rate

    def from_monotonic(self, t_monotonic: float) -> float:
        return (t_monotonic - self.epoch) * self.rate

    def scaled_ns(self) -> int:
        return int(time.monotonic_ns() * self.rate)

    def from_scaled(self, t_scaled: float) -> float:
        """A `scaled_ns() * 1e-9` time as onboard time."""
        return t_scaled - self.epoch * self.rate


@dc.dataclass
class RealtimeReport:
    sim_time: float          # s of diagram time advanced
    wall_time: float         # s
    ticks: int
    overruns: int            # ticks that ended more than `overrun_tolerance` behind the wall clock
    max_lag: float           # s, the largest delay behind the wall clock at the end of a tick
    interrupted: bool        # stopped by Ctrl-C / SIGTERM
    safe_stop: str           # what the final safe command did
    error: str = ""          # an exception that stopped the run, if any
    paced_wait: float = 0.0  # s of wall time spent waiting for the peer's clock (`pace`)
    cpu_time: float = 0.0    # s of this process's CPU time (all threads) during the run

    @property
    def realtime_rate(self) -> float:
        return self.sim_time / self.wall_time if self.wall_time > 0 else 0.0

    def lines(self) -> list[str]:
        return [f"ran {self.sim_time:.2f} s in {self.wall_time:.2f} s wall (rate "
                f"{self.realtime_rate:.3f}), {self.overruns} overruns of {self.ticks} ticks, "
                f"max lag {1e3 * self.max_lag:.1f} ms" + (", interrupted" if self.interrupted
                                                          else "")
                + (f", {self.paced_wait:.2f} s waiting for the autopilot's clock"
                   if self.paced_wait else "")
                + (f", {self.cpu_time / self.sim_time:.2f} CPU s per simulated s"
                   if self.sim_time > 0 else ""),
                f"final safe command: {self.safe_stop}"] + ([f"error: {self.error}"]
                                                             if self.error else [])


class Pacer:
    """Waits for a peer's clock (see `run_realtime`); returns the wall time waited."""

    def __init__(self, peer_time: Callable[[], float], stall: float):
        self._peer_time, self._stall = peer_time, stall
        self._last_seen, self._last_change = -math.inf, time.monotonic()
        self._stalled = False

    def wait_until(self, t: float) -> float:
        start = time.monotonic()
        while True:
            peer = self._peer_time()
            now = time.monotonic()
            if math.isfinite(peer) and peer > self._last_seen:
                self._last_seen, self._last_change = peer, now
                if self._stalled:
                    LOG.warning("the autopilot's clock moves again: pacing on it")
                    self._stalled = False
            if self._last_seen >= t:
                return now - start
            if now - self._last_change > self._stall:
                if not self._stalled:
                    LOG.warning("the autopilot's clock stopped for %.1f s: running on the wall "
                                "clock alone", self._stall)
                    self._stalled = True
                return now - start
            time.sleep(0.0005)


class LagReporter:
    """Counts the ticks that end late and, every `period` s of wall time in which some did, logs
    one warning with the achieved real-time rate over that period and the lag."""

    def __init__(self, rate: float, period: float, tolerance: float, note: str = ""):
        self._rate, self._period, self._tolerance = rate, period, tolerance
        self._note = note  # appended to each warning (why it may be late)
        self._window_start: tuple[float, float] | None = None  # (wall, sim) at its start
        self._late = 0
        self.warnings = 0

    def tick(self, t: float, lag: float, wall: float) -> bool:
        """Records a tick ending at simulated `t`, `lag` s behind; True when it was late."""
        if self._window_start is None:
            self._window_start = (wall, t)
        late = lag > self._tolerance
        self._late += late
        start_wall, start_t = self._window_start
        if wall - start_wall >= self._period:
            if self._late:
                self.warnings += 1
                LOG.warning("not keeping real time: %.2f x real time over the last %.1f s "
                            "(target %.2f), %d late ticks, %.0f ms behind at t = %.1f s%s",
                            (t - start_t) / (wall - start_wall), wall - start_wall, self._rate,
                            self._late, 1e3 * lag, t, self._note)
            self._window_start, self._late = (wall, t), 0
        return late


class RealtimeMeter:
    """The figures of a RealtimeReport as ticks come: ticks, overruns (a tick that ends more than
    `tolerance` behind `clock`), the largest lag, the wall time waited for a peer's clock, and the
    wall and CPU time since it was made; one warning per `warn_period` s of wall time that had
    an overrun (LagReporter)."""

    def __init__(self, clock: WallClock, tolerance: float, warn_period: float, note: str = ""):
        self._clock = clock
        self._lag_reporter = LagReporter(clock.rate, warn_period, tolerance, note)
        self.ticks = self.overruns = 0
        self.max_lag = self.paced_wait = 0.0
        self._wall_start, self._cpu_start = time.monotonic(), time.process_time()

    def tick(self, t: float) -> None:
        """A tick that advanced the diagram to `t` has ended."""
        self.ticks += 1
        lag = self._clock.now() - t
        self.max_lag = max(self.max_lag, lag)
        self.overruns += self._lag_reporter.tick(t, lag, time.monotonic())

    def report(self, sim_time: float, interrupted: bool = False, safe_stop: str = "",
               error: str = "") -> RealtimeReport:
        return RealtimeReport(sim_time, time.monotonic() - self._wall_start, self.ticks,
                              self.overruns, self.max_lag, interrupted, safe_stop, error,
                              self.paced_wait, time.process_time() - self._cpu_start)


class _StopRequest:
    """Ctrl-C (SIGINT) and SIGTERM set a flag that the loop reads between ticks. An exception
    raised from the signal handler would surface inside a Python system called by Drake's C++
    `AdvanceTo`, where it can be lost: the process then ignored Ctrl-C (measured: a
    sim-autopilot without a client ran on for more than 60 s)."""

    def __init__(self):
        self.requested = False

    def __call__(self, signum, frame):
        self.requested = True


def run_realtime(diagram, duration: float | None, clock: WallClock, seed: int = 0,
                 safe_stop: Callable[[], str] | None = None, tick: float = 0.01,
                 overrun_tolerance: float = 0.02, simulator: Simulator | None = None,
                 pace: Callable[[], float] | None = None, pace_stall: float = 1.0,
                 stop_when: Callable | None = None, warn_period: float = 5.0,
                 start_when: Callable[[], bool] | None = None
                 ) -> tuple[Simulator, RealtimeReport]:
    """Runs `diagram` in real time (at `clock.rate`) until `duration` (None: until Ctrl-C /
    SIGTERM) or until `stop_when(root_context)` is true after a tick (the mission is done).

    Each `tick` of diagram time is one `AdvanceTo`; a tick that ends more than
    `overrun_tolerance` behind the wall clock is an overrun (counted; one warning with the
    achieved rate per `warn_period` s of wall time that had any). `start_when` (optional) holds
    the start (time 0 of the diagram and of the clock) until it returns true, polled every 10 ms;
    Ctrl-C / SIGTERM while waiting ends the run before it starts. Whatever ends the
    run (the duration, Ctrl-C, SIGTERM, an exception), `safe_stop()` runs last and its answer is
    reported; an exception is re-raised after it.

    `pace` (optional) returns how far a simulated peer has got on our clock: each tick then also
    waits until the peer has reached it, so that a simulated autopilot that falls behind the wall
    clock (a loaded machine) slows the diagram down with it instead of seeing its commands
    squeezed or stretched. When the peer's time stops for `pace_stall` s of wall time (link
    lost), ticks stop waiting for it until it moves again."""
    simulator = simulator or Simulator(diagram)
    context = simulator.get_mutable_context()
    diagram.SetRandomContext(context, RandomGenerator(seed))
    simulator.set_target_realtime_rate(clock.rate)
    stop, previous = _install_stop_handlers()
    while start_when is not None and not stop.requested and not start_when():
        time.sleep(0.01)
    pacer = Pacer(pace, pace_stall) if pace is not None else None
    interrupted = False
    error = None
    clock.restart()
    meter = RealtimeMeter(clock, overrun_tolerance, warn_period,
                          " (paced by the autopilot's clock)" if pace is not None else "")
    try:
        simulator.Initialize()
        end = math.inf if duration is None else duration
        t = context.get_time()
        while t < end and not stop.requested:
            t = min(t + tick, end)
            if pacer is not None:
                meter.paced_wait += pacer.wait_until(t)
            simulator.AdvanceTo(t)
            meter.tick(t)
            if stop_when is not None and stop_when(context):
                break
    except KeyboardInterrupt:      # off the main thread the handlers are not installed
        interrupted = True
    except Exception as e:
        error = e
    finally:
        interrupted = interrupted or stop.requested
        _restore_handlers(previous)
        report = meter.report(context.get_time(), interrupted,
                              error="" if error is None else repr(error))
        stop_answer = "none (no vehicle hook)"
        if safe_stop is not None:
            try:
                stop_answer = safe_stop()
            except Exception as e:  # the report must still come back
                stop_answer = f"FAILED: {e}"
                LOG.error("final safe command failed: %s", e)
    report = dc.replace(report, safe_stop=stop_answer)
    if error is not None:
        LOG.error("real-time run stopped by an error; %s", "; ".join(report.lines()))
        raise error
    return simulator, report


def _install_stop_handlers() -> tuple[_StopRequest, dict]:
    """SIGINT and SIGTERM request a stop between ticks (main thread only)."""
    stop = _StopRequest()
    if threading.current_thread() is not threading.main_thread():
        return stop, {}
    return stop, {signum: signal.signal(signum, stop)
                  for signum in (signal.SIGINT, signal.SIGTERM)}


def _restore_handlers(previous: dict) -> None:
    for signum, handler in previous.items():
        signal.signal(signum, handler)
