"""HandSizer: `hand_measures: auto` without ROS: the first tracked second sizes the hand.

    sizer = HandSizer(make=lambda m: SimRuntime(params, measures=m, measures_source="auto"))
    sizer.add_frame(t, joints)    # each tracker frame: capture time [s], (26, 3|7) OpenXR joints [m]
    product = sizer.poll()        # None until the fitted hand is made, then once what make() returned

The sizer keeps the tracker frames until `seconds` of valid frames (at least MIN_FRAMES of them)
have arrived, then fits the measures (handmodel.fit.fit_measures, the rule of `softhand
calibrate`) and calls make(measures) in a worker thread (a daemon): the hand is morphed from the
default one or taken from the cache (handmodel.cache), the runtime built, in a few seconds, while
the caller's thread keeps running (the work is numpy: it releases the GIL in its heavy parts).
After that the sizer ignores frames. A failure (no valid fit, a build error) ends in state
'failed' with the reason in `error`; the caller then keeps the hand it has.

sim_node (hand_measures auto) waits for the fitted hand before it places any hand: it simulates
nothing until poll() hands over the new runtime (handover() carries the latest inputs to it).
One hand only: sim_node refuses `auto` with two hands (runtime.check_hand_measures).
"""
from __future__ import annotations

import functools
import threading
import time

import numpy as np

from softhand_sim import topics
from softhand_sim.handmodel.fit import MIN_FRAMES, fit_measures, frame_figures, hand_length

STATES = ("collecting", "building", "ready", "failed")


def tracker_topic(side: str) -> str:
    """The tracker topic the sizer listens to for hand `side`: that side's own frames,
    /tracker/{side}/hand_joints (softhand_sim.topics)."""
    return topics.tracker_topic(side)


def measures_diagnostics(measures, source: str) -> dict:
    """The /diagnostics values that say which hand is simulated: source (default | file | auto),
    hand length (wrist to middle tip), palm length and width [mm], and every bone's length
    (`hand_bone_lengths_mm`: 16 numbers, comma-separated, in the order of /hand/{side}/bones), so
    that a recording alone tells `softhand fidelity` where the simulated fingertips were."""
    return {"hand_measures_source": source, "hand_length_mm": round(hand_length(measures) * 1e3, 1),
            "palm_length_mm": round(measures.palm_length * 1e3, 1),
            "palm_width_mm": round(measures.palm_width * 1e3, 1),
            "hand_bone_lengths_mm": _bone_lengths_text(measures)}


@functools.lru_cache(maxsize=8)
def _bone_lengths_text(measures) -> str:
    # cached: diagnostics ask every second, the skeleton takes ~1 ms to build
    from softhand_sim.handmodel.skeleton import build_skeleton
    return ",".join(f"{1e3 * v:.2f}" for v in build_skeleton(measures)["bone_length"])


def bone_lengths_from_text(text: str) -> np.ndarray:
    """The bone lengths [m] (16,) of a `hand_bone_lengths_mm` value; ValueError if it is not 16
    positive numbers."""
    values = np.array([float(v) for v in str(text).split(",")]) * 1e-3
    if values.shape != (16,) or not np.all(values > 0.0):
        raise ValueError(f"hand_bone_lengths_mm must be 16 positive numbers, got {text!r}")
    return values


def handover(old, new):
    """Carry the inputs `old` (a SimRuntime) holds to `new`, which replaces it: the engine copies
    of the objects and the latest bone targets (placing the new hand there)."""
    if list(old.object_names) == list(new.object_names):
        new.copies = old.copies
    if old.bone_targets is not None:
        new.set_bone_targets(old.bone_targets, old.bone_target_stamp)
    return new


class HandSizer:
    """Tracker frames in, after the first `seconds` a product of the fitted measures (module doc).

    make: callable(HandMeasures) -> anything (run in the worker thread); side: 'right' | 'left'.
    """

    def __init__(self, make, side: str = "right", seconds: float = 1.0):
        if side not in ("right", "left"):
            raise ValueError(f"side must be 'right' or 'left', got {side!r}")
        self.make, self.side, self.seconds = make, side, float(seconds)
        self.state = "collecting"
        self.error = ""
        self.fit = None  # handmodel.fit.FitResult once fitted
        self.make_s = None  # [s] the worker's time for make()
        self._times, self._joints = [], []
        self._t_first = None
        self._product = None
        self._handed = False
        self._lock = threading.Lock()
        self._thread = None

    @property
    def frames(self) -> int:
        """Valid frames kept so far."""
        return len(self._times)

    @property
    def done(self) -> bool:
        """The product was handed over by poll(), or the sizing failed."""
        return self._handed or self.state == "failed"

    def add_frame(self, t: float, joints) -> None:
        """One tracker frame (capture time [s], joints (26, 3|7) [m]); invalid frames are ignored."""
        if self.state != "collecting":
            return
        joints = np.array(joints, dtype=np.float64)
        if frame_figures(joints, 1.0 if self.side == "right" else -1.0) is None:
            return
        self._times.append(float(t))
        self._joints.append(joints)
        self._t_first = float(t) if self._t_first is None else min(self._t_first, float(t))
        if float(t) >= self._t_first + self.seconds and len(self._times) >= MIN_FRAMES:
            self.state = "building"
            self._thread = threading.Thread(target=self._work, name="hand-sizer", daemon=True)
            self._thread.start()

    def _work(self):
        try:
            order = np.argsort(self._times, kind="stable")
            fit = fit_measures(np.asarray(self._times)[order], np.asarray(self._joints)[order],
                               seconds=self.seconds, hand=self.side)
            self.fit = fit
            t0 = time.perf_counter()
            product = self.make(fit.measures)
            self.make_s = time.perf_counter() - t0
            with self._lock:
                self._product, self.state = product, "ready"
        except Exception as exc:  # noqa: BLE001 - any failure leaves the caller on its current hand
            with self._lock:
                self.error, self.state = f"{type(exc).__name__}: {exc}", "failed"
        finally:
            self._times, self._joints = [], []

    def poll(self):
        """What make() returned, once (None before, and after it was handed over)."""
        with self._lock:
            if self.state != "ready" or self._handed:
                return None
            self._handed = True
            product, self._product = self._product, None
            return product

    def wait(self, timeout: float | None = None) -> str:
        """Block until the worker is done (tests, tools); returns the state."""
        if self._thread is not None:
            self._thread.join(timeout)
        return self.state

    def diagnostics(self) -> dict:
        """/diagnostics values: the sizing state, the frames kept, the fitted measures when known."""
        out = {"hand_measures_source": "auto", "hand_size_state": self.state, "hand_size_frames": self.frames}
        if self.fit is not None:
            out.update(measures_diagnostics(self.fit.measures, "auto"), hand_size_frames=self.fit.frames_used)
        if self.make_s is not None:
            out["hand_size_make_s"] = round(self.make_s, 2)
        if self.error:
            out.update(hand_measures_source="default", hand_size_error=self.error)  # the hand kept
        return out

    def describe(self) -> str:
        """One log line: the fitted size and how long it took, or the error."""
        if self.state == "failed":
            return f"hand size not fitted ({self.error}); keeping the default hand"
        if self.fit is None:
            return f"hand size: {self.state}, {self.frames} frames"
        d = measures_diagnostics(self.fit.measures, "auto")
        return (f"hand fitted on {self.fit.frames_used} frames over {self.fit.window_s:.2f} s: "
                f"{d['hand_length_mm']} mm wrist to middle tip, palm {d['palm_length_mm']} x {d['palm_width_mm']} mm"
                + (f", ready in {self.make_s:.2f} s" if self.make_s is not None else ""))
