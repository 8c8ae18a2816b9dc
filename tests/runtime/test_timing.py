"""softhand_sim.timing: the fixed-rate scheduler and step statistics the nodes' /diagnostics read.

Driven by synthetic clocks (integer nanoseconds), never by sleeping: the schedule is a function of
the times passed in.
"""
import numpy as np
import pytest

from softhand_sim import timing
from softhand_sim.timing import FixedRateScheduler, StepStats

MS = 1_000_000  # [ns]


def run(scheduler, now_ns):
    return list(scheduler.due(now_ns))


def test_on_time_ticks_run_one_step_each_at_its_own_time():
    """100 Hz ticked exactly on time (and with sub-period jitter): one step per tick, no late/skipped."""
    s = FixedRateScheduler(100.0, max_catch_up=4)
    t0 = 5_000 * MS
    assert run(s, t0) == [t0]  # the first call starts the schedule at now
    jitter = np.random.default_rng(0).integers(0, 9 * MS, size=50)
    for k in range(1, 51):
        assert run(s, t0 + k * 10 * MS + int(jitter[k - 1])) == [t0 + k * 10 * MS]
    assert run(s, t0 + 505 * MS) == []  # early tick: nothing due yet
    assert (s.steps, s.late_steps, s.skipped_steps, s.resyncs, s.clock_resets) == (51, 0, 0, 0, 0)


def test_catch_up_after_a_short_stall_runs_the_missed_steps():
    """A tick 35 ms after the last at 100 Hz: it runs the 3 due steps with their own times, 2 of them late."""
    s = FixedRateScheduler(100.0, max_catch_up=4, first_due_ns=10 * MS)
    assert run(s, 10 * MS) == [10 * MS]
    assert run(s, 20 * MS) == [20 * MS]
    assert run(s, 55 * MS) == [30 * MS, 40 * MS, 50 * MS]
    assert run(s, 60 * MS) == [60 * MS]  # back on the original phase
    assert (s.steps, s.late_steps, s.skipped_steps, s.resyncs) == (6, 2, 0, 0)


def test_long_stall_is_bounded_and_skips_ahead_on_phase():
    """A 1 s stall at 250 Hz with at most 25 catch-up steps: 25 run, the rest counted as skipped,
    and the schedule resumes on its phase strictly after now."""
    s = FixedRateScheduler(250.0, max_catch_up=25)
    assert s.period_ns == 4 * MS
    assert run(s, 0) == [0]
    now = 1_000 * MS + 1 * MS  # 1001 ms: steps at 4, 8, ..., 1000 ms are due (250 of them)
    steps = run(s, now)
    assert steps == [4 * MS * k for k in range(1, 26)]
    assert (s.late_steps, s.skipped_steps, s.resyncs) == (24, 225, 1)
    assert s.next_ns == 1_004 * MS
    assert run(s, 1_003 * MS) == []
    assert run(s, 1_004 * MS) == [1_004 * MS]
    assert s.steps == 27 and s.steps + s.skipped_steps == 1_004 // 4 + 1  # every period either run or skipped


def test_clock_going_back_restarts_the_schedule_beyond_the_tolerance():
    """Within clock_back_ns of the last step the schedule waits; further back it restarts at now."""
    s = FixedRateScheduler(100.0, max_catch_up=4, clock_back_ns=1_000 * MS)
    run(s, 0)
    for k in range(1, 101):
        run(s, k * 10 * MS)  # last step at 1000 ms
    assert run(s, 500 * MS) == []  # 0.5 s back: not a restart, wait for the schedule
    assert s.clock_resets == 0
    assert run(s, -1 * MS) == [-1 * MS]  # 1.001 s behind the last step: restart at now
    assert s.clock_resets == 1
    assert run(s, 9 * MS) == [9 * MS]
    # default tolerance: one period (the tracking loop's behaviour)
    d = FixedRateScheduler(100.0, max_catch_up=4)
    run(d, 100 * MS)  # last step at 100 ms
    assert run(d, 92 * MS) == [] and d.clock_resets == 0
    assert run(d, 89 * MS) == [89 * MS] and d.clock_resets == 1


def test_scheduler_refuses_bad_settings():
    with pytest.raises(ValueError, match="rate_hz"):
        FixedRateScheduler(0.0, max_catch_up=1)
    with pytest.raises(ValueError, match="max_catch_up"):
        FixedRateScheduler(100.0, max_catch_up=0)


def test_step_stats_percentiles_match_numpy_and_known_values():
    """On 1..100 ms the median is 50.5 and p99 99.01 (linear interpolation); random data matches numpy."""
    st = StepStats(window=1000)
    for v in range(1, 101):
        st.add(v)
    assert st.median() == pytest.approx(50.5)
    assert st.percentile(99) == pytest.approx(99.01)
    assert st.max() == 100.0 and st.count == 100 and len(st) == 100
    data = np.random.default_rng(1).lognormal(0.0, 1.0, size=700)
    r = StepStats(window=1000)
    for v in data:
        r.add(v)
    assert r.median() == pytest.approx(np.median(data), rel=1e-12)
    assert r.percentile(99) == pytest.approx(np.percentile(data, 99), rel=1e-12)
    assert r.max() == data.max()


def test_step_stats_window_is_bounded_counts_are_not():
    """2,500 values in a window of 1,000: statistics over the last 1,000, count and over_budget over all."""
    data = np.r_[np.full(1_500, 50.0), np.arange(1_000, dtype=float) * 0.01]  # the slow ones fall out
    st = StepStats(window=1_000, budget=4.0)
    for v in data:
        st.add(v)
    assert len(st) == 1_000 and st.count == 2_500
    np.testing.assert_array_equal(st.values(), data[-1_000:])
    assert st.max() == pytest.approx(9.99)
    assert st.percentile(99) == pytest.approx(np.percentile(data[-1_000:], 99))
    assert st.over_budget == 1_500 + int(np.sum(data[-1_000:] > 4.0))  # 1,500 + 599


def test_step_stats_empty_is_nan():
    st = StepStats(window=10)
    assert np.isnan(st.median()) and np.isnan(st.percentile(99)) and np.isnan(st.max())
    assert st.count == 0 and st.over_budget == 0 and len(st) == 0
    with pytest.raises(ValueError, match="window"):
        StepStats(window=0)


def test_slow_motion_warns_only_a_loop_behind_real_time_without_max_step():
    """timing.slow_motion: a 200 Hz loop whose ticks come every 5.7 ms (175 Hz) after 300 steps is
    behind real time, and the warning names the period, the rate and both remedies; the same loop
    within 10 % of its rate, before SLOW_MOTION_STEPS steps, or with max_step above its period
    (longer steps keep real time) is not."""
    dt = 1.0 / 200.0
    text = timing.slow_motion(175.4, 300, dt, 0.0, 4.6)
    assert text is not None
    for part in ("ticks every 5.7 ms", "step p50 4.6 ms", "sim_rate 200 Hz", "simulates 5.0 ms",
                 "lower sim_rate", "max_step (e.g. 0.01 s)"):
        assert part in text, (part, text)
    assert timing.slow_motion(181.0, 300, dt, 0.0, 4.6) is None   # 0.905 of the rate
    assert timing.slow_motion(175.4, timing.SLOW_MOTION_STEPS - 1, dt, 0.0, 4.6) is None
    assert timing.slow_motion(175.4, 300, dt, 0.01, 4.6) is None  # max_step keeps real time
    assert timing.slow_motion(175.4, 300, dt, dt, 4.6) is not None  # max_step <= dt: no longer steps
