"""A speed-adaptive low-pass on the tracked joint positions: the One Euro filter.

Casiez, Roussel, Vogel 2012, "1 Euro Filter: A Simple Speed-based Low-pass Filter for Noisy Input in
Interactive Systems". Each joint position is smoothed by a first-order low-pass whose cutoff grows
with the joint's speed:

    cutoff = min_cutoff + beta * |filtered velocity|        [Hz]

so a hand held still is smoothed hard (the tracker's millimetre jitter removed) and a moving hand
hardly at all (little lag where lag shows). The tracker adapter filters the joints relative to the
tracked wrist: the fingers' motion against each other and the hand's turning are smoothed, the
hand's travel passes unfiltered.

Why it is here: tracker jitter of the phalanxes against each other walks a held object out of the
grip. The two-hand lift's box slid 10-13 mm relative to the palms in the hold with 1.5 mm of noise
per joint (the sample bags' until they took a real tracker's 0.05 mm: 0.4 mm then), 0.2 mm without
it, 2 mm with the same noise as one offset of the whole hand; with this filter (1 Hz, 30 s/m) 4.8 /
3.9 mm. What it costs is lag of the fingers in motion: +6-7 ms on the real recordings (README,
"Filtering the tracked joints"). So it is off by default.

Per joint, not per coordinate: the speed that opens the cutoff is the norm of the joint's smoothed
3D velocity, so a motion along one axis is not smoothed differently from the same motion along
another. As in the authors' Python reference, the velocity is taken against the last filtered
position, so a lagging output raises its own cutoff (on a ramp the lag settles where
tau = 1 / (2 pi fc) and the speed estimate v (1 + tau / dt) agree). Time is the frames' capture time, so irregular frame spacing (a tracker's jitter, a
replay's bursts) is filtered by its real spacing. The reference implementation (the authors'
`1eurofilter` package) filters one scalar per object; this is the same recurrence on a (26, 3)
array per frame.
"""
from __future__ import annotations

import math

import numpy as np

D_CUTOFF = 1.0  # [Hz] cutoff of the velocity estimate's own low-pass (the paper's default)


def smoothing_factor(dt: float, cutoff) -> np.ndarray:
    """alpha of an exponential low-pass with `cutoff` [Hz] for a sample `dt` [s] after the last."""
    tau = 1.0 / (2.0 * math.pi * np.asarray(cutoff, dtype=np.float64))
    return 1.0 / (1.0 + tau / dt)


class OneEuroJointFilter:
    """`filter(joints (n, 3), t [s]) -> (n, 3)`; `reset()` forgets the past (the next frame passes
    as it is). `min_cutoff` [Hz] > 0, `beta` [s/m] >= 0 (cutoff Hz per m/s of joint speed)."""

    def __init__(self, min_cutoff: float = 1.0, beta: float = 30.0, d_cutoff: float = D_CUTOFF):
        for name, value, low in (("min_cutoff", min_cutoff, 0.0), ("d_cutoff", d_cutoff, 0.0)):
            if not (math.isfinite(value) and value > low):
                raise ValueError(f"joint filter {name} must be > 0 Hz, got {value!r}")
        if not (math.isfinite(beta) and beta >= 0.0):
            raise ValueError(f"joint filter beta must be >= 0 s/m, got {beta!r}")
        self.min_cutoff, self.beta, self.d_cutoff = float(min_cutoff), float(beta), float(d_cutoff)
        self.reset()

    def __str__(self) -> str:  # as tracking_node's /diagnostics names it
        return f"one_euro (min cutoff {self.min_cutoff:g} Hz, beta {self.beta:g} s/m)"

    def reset(self) -> None:
        self._t = None
        self._x = None
        self._dx = None

    def filter(self, joints, t: float) -> np.ndarray:
        x = np.asarray(joints, dtype=np.float64)
        dt = None if self._t is None else t - self._t
        if dt is None or not dt > 0.0 or self._x is None or self._x.shape != x.shape:
            # the first frame, or one not after the last (the caller refuses those while tracking;
            # after a hold it resyncs): start afresh from it
            self._t, self._x, self._dx = t, x.copy(), np.zeros(x.shape)
            return x.copy()
        self._dx += smoothing_factor(dt, self.d_cutoff) * ((x - self._x) / dt - self._dx)
        speed = np.linalg.norm(self._dx, axis=1)  # of the smoothed velocity: noise averages out first
        alpha = smoothing_factor(dt, self.min_cutoff + self.beta * speed)
        self._x += alpha[:, None] * (x - self._x)
        self._t = t
        return self._x.copy()
