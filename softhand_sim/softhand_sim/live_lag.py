"""LiveLag: how far the intermediate and the simulated hand trail the tracked hand, while running.

    lag = LiveLag(hand="right")
    lag.add_frame(stamp, joints)                # each tracker frame (26, 3|7): the adapter's bones
    lag.add("intermediate", stamp, poses)       # each /hand/{side}/intermediate_bones (16, 7)
    lag.add("sim", stamp, poses)                # each /hand/{side}/bones
    lag.report()  -> {"intermediate_lag_ms": ..., "sim_lag_ms": ..., "sim_lag_palm_ms": ...}

All three are stamped on one clock (docs/INTERFACE.md "Stamps and clocks"): tracker frames with
their capture time, the layers with the time of their state. record_node, which hears all three,
keeps the last WINDOW_S of each and, once per /diagnostics report, aligns each layer with the
tracked bones the way `softhand lag` aligns a recording (softhand_sim.commands.lag.layer_lag: the
time shift that best aligns the phalanx directions, and the palm position), so the lag can be
watched live (the Foxglove layout plots it) as well as measured afterwards.

A lag is only defined while the hand moves: a window in which the tracked phalanx directions spread
less than MIN_TURN_RAD from their mean reports NaN, and likewise the palm's lag when the palm
spreads less than MIN_TRAVEL_M (commands/lag.py's rule and `spread`, which a whole recording's
lag follows too). The intermediate (250 Hz) and simulated (200 Hz for one hand) layers are kept at
LAYER_HZ: the search interpolates the tracked frames at each kept sample's time, so fewer samples
still give the lag to the millisecond, and the cost of a report follows the samples kept: on the
demo's recording (one hand, the simulated layer then at 150 Hz) a report took 70-96 ms of the
recorder's CPU with that layer kept whole, 53-56 ms thinned. `wants` lets the recorder skip a
thinned sample before it parses the message (36 instead of 54 us per message fed).

With two hands the recorder reports one hand per period, the hands taking turns (`HandLags`): both
every period took ~20 % of a core in a two-hand demo, whose sim_node then fell short of its rate.
"""
from __future__ import annotations

import threading
from collections import deque

import numpy as np

from softhand_sim.commands.lag import MIN_TRAVEL_M, MIN_TURN_RAD, Series, layer_lag, spread

WINDOW_S = 2.0          # [s] the stretch of each layer aligned per report
LAYER_HZ = 60.0  # [Hz] intermediate and simulated bones kept at most this often
SHIFT_RANGE_MS = (-40.0, 160.0)  # [ms] lags searched (the recording tool searches -60..250)
LAYERS = ("tracked", "intermediate", "sim")


class LiveLag:
    """The last WINDOW_S of one hand's tracked, intermediate and simulated bones, and their lags."""

    def __init__(self, hand: str = "right", window_s: float = WINDOW_S):
        from softhand_tracking.adapter import AdapterConfig, TrackerAdapter
        self.adapter = TrackerAdapter(AdapterConfig(hand=hand))  # the tracking node's default conversion
        self.window_s = float(window_s)
        self._data = {layer: deque() for layer in LAYERS}
        self._lock = threading.Lock()  # add() in the recorder's callbacks, report() in its own thread

    def add_frame(self, t: float, joints) -> None:
        """A tracker frame (26, 3|7) captured at t [s]; one the adapter rejects is left out."""
        poses = self.adapter.convert(np.asarray(joints, dtype=np.float64)[:, :3])
        if poses is not None:
            self.add("tracked", t, poses)

    def wants(self, layer: str, t: float) -> bool:
        """Whether add(layer, t, ...) keeps a sample at t [s] (the recorder asks before it parses a
        message): one newer than the layer's last, and for the two thinned layers at least
        1 / LAYER_HZ newer; or one older than the window (a replay restarted its clock)."""
        buf = self._data[layer]
        if not buf:
            return True
        last = buf[-1][0]
        if t < last - self.window_s:
            return True
        return t > last and (layer == "tracked" or t - last >= 1.0 / LAYER_HZ)

    def add(self, layer: str, t: float, poses) -> None:
        """Bones (16, 7) of `layer` at time t [s], kept as `wants` says; one older than the window
        starts the layer afresh."""
        buf = self._data[layer]
        with self._lock:
            if not self.wants(layer, t):
                return
            if buf and t < buf[-1][0] - self.window_s:
                buf.clear()
            buf.append((float(t), np.array(poses, dtype=np.float64)))
            while buf and buf[0][0] < t - self.window_s:
                buf.popleft()

    def _series(self, layer: str) -> Series | None:
        with self._lock:
            rows = list(self._data[layer])
        if len(rows) < 3:
            return None
        return Series(np.array([t for t, _ in rows]), np.stack([p for _, p in rows]))

    def report(self) -> dict:
        """intermediate_lag_ms (phalanx directions), sim_lag_ms (phalanx directions) and
        sim_lag_palm_ms [ms]; NaN where a layer has no samples or the hand hardly moved."""
        out = {"intermediate_lag_ms": float("nan"), "sim_lag_ms": float("nan"), "sim_lag_palm_ms": float("nan")}
        ref = self._series("tracked")
        if ref is None:
            return out
        turn, travel = spread(ref)
        if turn < MIN_TURN_RAD and travel < MIN_TRAVEL_M:
            return out
        for layer, (key, palm_key) in (("intermediate", ("intermediate_lag_ms", None)),
                                       ("sim", ("sim_lag_ms", "sim_lag_palm_ms"))):
            series = self._series(layer)
            if series is None:
                continue
            r = layer_lag(ref, series, SHIFT_RANGE_MS, ref_spread=(turn, travel))  # NaN where still
            out[key] = round(r["lag_phalanx_ms"], 1)
            if palm_key:
                out[palm_key] = round(r["lag_palm_ms"], 1)
        return out


class HandLags:
    """A LiveLag per hand, reported one hand at a time: `report_next()` reports the next of the
    hands heard from (those fed a sample, sorted), in turn, so a report costs one hand's search
    whatever the number of hands, and with two each hand's figures are refreshed every second call."""

    def __init__(self, sides, window_s: float = WINDOW_S):
        self.lags = {side: LiveLag(hand=side, window_s=window_s) for side in sides}
        self.heard = set()  # sides fed at least one sample (only those are reported)
        self._turn = 0

    def __getitem__(self, side: str) -> LiveLag:
        return self.lags[side]

    def heard_from(self, side: str) -> None:
        self.heard.add(side)

    def report_next(self):
        """(side, report) of the next hand in turn; None before any hand was heard from."""
        sides = sorted(self.heard.copy())  # copy(): the recorder's callbacks add to it meanwhile
        if not sides:
            return None
        side = sides[self._turn % len(sides)]
        self._turn += 1
        return side, self.lags[side].report()
