"""The arbiter of the bank of filters, M Sec. 3.5: which hypothesis is the output.

In order of precedence: a request for a particular filter (the mission or UAV manager), if that
filter is reliable; a switch away from the active filter when it is unreliable; otherwise the
filter of minimum covariance trace, with hysteresis (a switch needs `switch_ratio` x the active
trace and `min_dwell` s on the active filter, so that two close hypotheses do not chatter).

A filter is unreliable while it is not initialized, while a source it fuses has stopped (no new
measurement for that source's `timeout`), or once its innovations have failed the chi-square gate
for `unreliable_after` s in a row; it is reliable again after `recover_time` s without either.
"""
import dataclasses as dc

import numpy as np

from alight.systems.params import bounded


@dc.dataclass
class ArbiterParams:
    initial: str = ""                                       # the first output (default: first)
    gate_probability: float = bounded(0.999, 0.5, 0.9999999)  # chi-square quantile of the gate
    unreliable_after: float = bounded(0.5, 0.0, 60.0, "s")  # gate failing this long
    reset_after: float = bounded(3.0, 0.0, 600.0, "s")      # then re-initialize from the source
    recover_time: float = bounded(1.0, 0.0, 60.0, "s")      # healthy this long: reliable again
    switch_ratio: float = bounded(0.5, 0.0, 1.0)            # min-trace switch threshold
    min_dwell: float = bounded(2.0, 0.0, 600.0, "s")        # on the active filter before that


@dc.dataclass
class Health:
    """What the arbiter knows about one filter."""
    initialized: bool = False
    stopped: bool = True              # a fused source has no recent measurement
    # per fused quantity: first gate failure since its last accepted measurement (nan: none)
    rejecting_since: np.ndarray = dc.field(default_factory=lambda: np.zeros(0))
    healthy_since: float = np.nan     # since when initialized, not stopped, not rejecting long
    reliable: bool = False

    def update(self, now: float, params: ArbiterParams) -> None:
        rejecting = bool(np.any(now - self.rejecting_since >= params.unreliable_after))
        healthy = self.initialized and not self.stopped and not rejecting
        if not healthy:
            self.healthy_since = np.nan
        elif not np.isfinite(self.healthy_since):
            self.healthy_since = now
        self.reliable = healthy and now - self.healthy_since >= params.recover_time


def choose(active: int, active_since: float, now: float, health: list[Health],
           traces: list[float], request: int, params: ArbiterParams) -> int:
    """The index of the filter to output this tick (M Sec. 3.5)."""
    reliable = [i for i, h in enumerate(health) if h.reliable]
    if 0 <= request < len(health) and health[request].reliable:
        return request
    if not reliable:
        return active
    best = min(reliable, key=lambda i: traces[i])
    if not health[active].reliable:
        return best
    if request == active:
        return active
    if best != active and traces[best] < params.switch_ratio * traces[active] \
            and now - active_since >= params.min_dwell:
        return best
    return active
