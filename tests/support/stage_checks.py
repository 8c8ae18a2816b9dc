"""Shared check of a per-stage step profile (tests/physics/test_step_stages.py and
tests/runtime/test_runtime_stages.py): the stages are finite, non-negative, never more than the
step measured around the call, and cover at least MIN_COVERED of it over the run."""
import numpy as np

MIN_COVERED = 0.9  # measured 99-100 %; a dropped stage of any weight falls below


def check_stage_coverage(label, totals, stages, names):
    """totals (n,) [ms] measured around each step; stages (n, k) [ms] in the order of names."""
    totals, stages = np.asarray(totals), np.asarray(stages)
    covered = stages.sum() / totals.sum()
    print(f"{label}step median {np.median(totals):.3f} ms, stages cover {100 * covered:.2f}%; medians",
          dict(zip(names, np.round(np.median(stages, axis=0), 4))))
    assert np.all(np.isfinite(stages)) and np.all(stages >= 0.0)
    assert np.all(stages.sum(axis=1) <= totals), (stages.sum(axis=1) - totals).max()
    assert covered >= MIN_COVERED
