"""When to keep the factor preconditioner's factor instead of starting the next factorization.

The factor preconditioner (pcg.Factor) used to start a new factorization as soon as the last one
was in use: the coarse hand factored its matrix every step (one slice, ~40 % of its step), the
fine hand always had one in progress (a slice a step). While the hand holds still, or moves little
from one step to the next, the factor in use stays a good preconditioner for many steps: CG
still takes one or two iterations on it, and the factorization buys nothing. Whether it will is
known only afterwards, so the rule is the one for renting against buying (ski rental): keep the
factor in use while the CG iterations it has cost beyond the one a fresh factor needs, summed
since it came into use, stay under a budget worth a fraction of a factorization (`factor_hold`
times the factorization's cost in iterations, from their flops: pcg.Factor.iterations_per_factor).
Between two factorizations the held steps' extra iterations then cost at most that fraction of a
factorization, plus one step's overshoot. At 1, the default, that is renting until the rent paid
equals the price of buying, the break-even rule: each hold taken alone, whatever the motion, it
costs at most about twice what the best choice made knowing the motion in advance would. The
unit is only as good as the cost model that converts a factorization into iterations
(pcg.Factor.analyse; `softhand bench --profile` prints it against the measured one). The decision
reads iteration counts only, never the clock: a run stays deterministic.

The last held step's excess is the forecast of the next one's: once a step takes as many
iterations beyond one as the budget has left, the next step starts a factorization. A first hold
that fails at once (its one step over the budget: a motion too fast for even a one-step-old
factor, such as two coarse hands at 50 Hz, 5-12 iterations) is retried only after 1, 2, 4, ...
(at most MAX_BACKOFF) factorizations, so a fast motion pays a failed hold now and then, not
every other step. On a kept factor CG may take at most a factorization's worth of iterations;
a held step that needs more factors its own matrix and goes on from where CG stopped
(Solver.step): a kept factor never costs more than about two factorizations' time in a step, nor
a rejected step.
"""

MAX_BACKOFF = 64  # factorizations between two attempts to hold, at most


class FactorHold:
    """The hold decision of one solver. `fraction` = the factor_hold parameter (0: never hold, a
    new factorization whenever the last one is done, as before it existed).

        keep(last_iters, iterations_per_factor) -> bool   at a step where a factorization could start
        published()                                        when a new factor comes into use
        rescued()                                          when a held step had to factor (Solver.step)
    """

    def __init__(self, fraction):
        if fraction < 0.0:
            raise ValueError(f"factor_hold={fraction}: must be >= 0")
        self.fraction = float(fraction)
        self.held = 0           # steps the factor in use has been held
        self.excess = 0.0       # their CG iterations beyond one, summed
        self.wait = 0           # factorizations to start before the next attempt to hold
        self.backoff = 0        # the wait set after the last failed attempt

    def keep(self, last_iters, iterations_per_factor):
        """True to hold the factor in use for this step; last_iters: the last step's CG."""
        budget = self.fraction * iterations_per_factor
        if budget <= 0.0:
            return False
        over_one = max(int(last_iters) - 1, 0)
        if self.held > 0:
            self.excess += over_one  # the outcome of the last held step
            if self.held == 1:       # the first one: did holding pay at all?
                if self.excess >= budget:
                    self._back_off()
                else:
                    self.backoff = self.wait = 0
        elif self.wait > 0:
            self.wait -= 1
            return False
        if self.excess + over_one >= budget:
            return False
        self.held += 1
        return True

    def published(self):
        self.held = 0
        self.excess = 0.0

    def rescued(self):
        """A held step's CG ran past its limit and the step factored its own matrix: a failed
        hold (it backs off as one), and the new factor in use."""
        self._back_off()
        self.published()

    def _back_off(self):
        """A failed hold: the next attempt waits 1, 2, 4, ... MAX_BACKOFF factorizations."""
        self.backoff = min(max(1, 2 * self.backoff), MAX_BACKOFF)
        self.wait = self.backoff
