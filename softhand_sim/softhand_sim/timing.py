"""Fixed-rate loop timing shared by the nodes: when steps are due, and how long they took.

FixedRateScheduler says, from the current time, which steps of a fixed-rate loop are due (a late
tick runs the steps it missed, up to a bound; beyond it the loop skips ahead on its own phase).
StepStats keeps a bounded window of per-step values (compute time, CG iterations) for /diagnostics.
Pure Python + numpy, no ROS: the nodes pass in their clock's time, so wall time and /clock
(use_sim_time) behave alike, and both are testable on synthetic time series.
"""
from __future__ import annotations

import math
from collections import deque
from typing import Optional

import numpy as np


class FixedRateScheduler:
    """Step times of a loop at `rate_hz` on a caller-supplied clock (integer nanoseconds).

    `due(now_ns)` returns the times [ns] of the steps to run now, oldest first, as a range: one
    step per period on time; after a stall the missed ones too (each run with its own time, so the
    loop keeps its rate on average on a busy machine), but at most `max_catch_up` per call. Still
    behind after that, the missed steps are given up (`skipped_steps`, one `resyncs` event) and the
    schedule jumps ahead by whole periods, keeping its phase. A clock that goes back more than
    `clock_back_ns` behind the last step run (bag restart, /clock reset) restarts the schedule at
    now (`clock_resets`). Counters: `steps` run, `late_steps` (steps beyond the first in one call,
    i.e. run late by a catch-up), `skipped_steps`, `resyncs`, `clock_resets`.
    """

    def __init__(self, rate_hz: float, max_catch_up: int, clock_back_ns: Optional[int] = None,
                 first_due_ns: Optional[int] = None):
        if not (rate_hz > 0 and math.isfinite(rate_hz)):
            raise ValueError(f"rate_hz must be a positive number, got {rate_hz!r}")
        if int(max_catch_up) < 1:
            raise ValueError(f"max_catch_up must be at least 1, got {max_catch_up!r}")
        self.period_ns = int(round(1e9 / rate_hz))
        self.max_catch_up = int(max_catch_up)
        # default: a clock that went back more than one period restarts the schedule
        self.clock_back_ns = self.period_ns if clock_back_ns is None else int(clock_back_ns)
        self.next_ns = None if first_due_ns is None else int(first_due_ns)  # None: first call starts at now
        self.steps = 0
        self.late_steps = 0
        self.skipped_steps = 0
        self.resyncs = 0
        self.clock_resets = 0

    def due(self, now_ns: int) -> range:
        """Times [ns] of the steps due at `now_ns`, oldest first; the schedule moves past them."""
        now_ns = int(now_ns)
        if self.next_ns is None:
            self.next_ns = now_ns
        elif now_ns < self.next_ns - self.period_ns - self.clock_back_ns:
            self.next_ns = now_ns  # the clock went back: start again from now
            self.clock_resets += 1
        if now_ns < self.next_ns:
            return range(0)
        behind = (now_ns - self.next_ns) // self.period_ns + 1  # steps due, the one at next_ns included
        n = min(behind, self.max_catch_up)
        out = range(self.next_ns, self.next_ns + n * self.period_ns, self.period_ns)
        self.next_ns += behind * self.period_ns  # next step strictly after now, same phase
        self.steps += n
        self.late_steps += n - 1
        if behind > n:  # hopelessly behind (stalled process, clock jump forward): give those up
            self.skipped_steps += behind - n
            self.resyncs += 1
        return out


class StepStats:
    """Per-step values (e.g. compute time [ms]) over the last `window` steps, for /diagnostics.

    `add(value)` per step. `count` is every value added, `over_budget` how many exceeded `budget`
    (when given; same unit as the values), both since the start; median(), percentile(q) and max()
    are over the window, NaN while it is empty.
    """

    def __init__(self, window: int, budget: Optional[float] = None):
        if int(window) < 1:
            raise ValueError(f"window must be at least 1, got {window!r}")
        self._values = deque(maxlen=int(window))
        self.budget = None if budget is None else float(budget)
        self.count = 0
        self.over_budget = 0

    def add(self, value: float) -> None:
        value = float(value)
        self._values.append(value)
        self.count += 1
        if self.budget is not None and value > self.budget:
            self.over_budget += 1

    def __len__(self) -> int:
        """Values in the window."""
        return len(self._values)

    def values(self) -> np.ndarray:
        """The window, oldest first."""
        return np.fromiter(self._values, dtype=float, count=len(self._values))

    def percentile(self, q: float) -> float:
        """q-th percentile (0..100, numpy's linear interpolation) of the window; NaN if empty."""
        return float(np.percentile(self.values(), q)) if self._values else math.nan

    def percentiles(self, *qs: float) -> tuple:
        """Several percentiles (0..100, the rule of `percentile`) from one sort: np.percentile costs
        ~0.2 ms a call, ~5 ms for sim_node's dozen stages in each /diagnostics report."""
        if not self._values:
            return tuple(math.nan for _ in qs)
        window = np.sort(self.values())
        at = np.interp(np.array(qs, dtype=float) / 100.0 * (len(window) - 1), np.arange(len(window)), window)
        return tuple(float(v) for v in at)

    def median(self) -> float:
        return self.percentile(50.0)

    def max(self) -> float:
        return max(self._values) if self._values else math.nan


SLOW_MOTION_SHARE = 0.9  # a loop at less than this share of its rate is behind real time
SLOW_MOTION_STEPS = 200  # ... measured over at least this many steps (not the start-up's first)


def slow_motion(rate_hz, steps, dt, max_step, step_ms_p50):
    """The warning for a sim loop that steps dt [s] a tick but ticks at rate_hz < 1/dt (its median
    period's inverse, after `steps` >= SLOW_MOTION_STEPS), with max_step <= dt (no longer steps to
    keep real time); None when it keeps its rate or keeps real time. Such a loop takes its targets
    and the world's copies at the wall clock's time but simulates only dt of the longer time
    between its ticks: the hand is pulled toward targets that run ahead of it and a gripped object
    between two clocks (measured: the fine hand at 200 Hz stepping at 134-144 Hz threw the ball of
    grasp_lift a metre up; with max_step 0.01 s it lifted it 17.4 cm as offline)."""
    if max_step > dt or steps < SLOW_MOTION_STEPS or not rate_hz * dt < SLOW_MOTION_SHARE:
        return None
    return (f"behind real time: ticks every {1e3 / rate_hz:.1f} ms (median; step p50 {step_ms_p50:.1f} ms) "
            f"for sim_rate {1.0 / dt:g} Hz, and each simulates {1e3 * dt:.1f} ms, so the hand falls behind "
            f"its targets and the world (a gripped object can be thrown); lower sim_rate, or set max_step "
            f"(e.g. {2 * dt:.3g} s) to keep real time")
