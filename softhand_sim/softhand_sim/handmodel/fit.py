"""The user's hand measures from tracker frames (no ROS): bone lengths, palm, knuckles, thumb CMC.

    from softhand_sim.handmodel.fit import fit_measures
    result = fit_measures(times_s, joints)      # joints (n, 26, 3 or 7), OpenXR order [m]
    result.measures                             # HandMeasures at the tracked hand's size

What is measured, per frame (positions only; orientations are not used):
* the 16 tracked segment lengths (`skeleton_names.BONE_SEGMENTS`): palm = WRIST -> MIDDLE_PROXIMAL,
  the thumb's metacarpal, proximal and distal (IP -> TIP), each finger's proximal, intermediate
  and distal (DIP -> TIP), as HandMeasures defines them;
* in the tracked palm frame (origin WRIST, x toward MIDDLE_PROXIMAL, z dorsal = side * x ×
  (INDEX_PROXIMAL - LITTLE_PROXIMAL), the adapter's palm frame): the index, ring and little
  knuckles (F_PROXIMAL) and the thumb CMC (THUMB_METACARPAL).
All of these are rigid in a hand (they do not change with the pose), so a robust location over
frames is the estimate:
1. frames with a non-finite coordinate, a segment outside [SEGMENT_MIN, SEGMENT_MAX] or a
   degenerate palm are invalid and skipped;
2. the window is the first `seconds` of valid frames (from the first valid frame's time to the
   first frame at or past `seconds` later);
3. outlier frames are rejected: a frame is out when any of its figures is farther from that
   figure's median over the window than max(OUTLIER_SIGMAS * 1.4826 MAD, OUTLIER_FLOOR);
4. each figure is the median over the remaining frames; a segment length less the bias that
   position noise across the segment adds (estimated from the spread of that length).

Not measurable from a PoseArray: joint radii (OpenXR sends a radius per joint, PoseArray has no
field for it), hence finger widths and palm thickness. They are the defaults scaled by the
tracked hand's length (wrist to middle tip) over the default's, clamped to WIDTH_SCALE_RANGE.
The rest spread of the fingers is a pose, not a measure: it keeps its default.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from softhand_sim.handmodel.measures import _LAYOUT_RANGES, FINGERS4, HandMeasures
from softhand_sim.handmodel.skeleton import knuckle_span
from softhand_sim.handmodel.skeleton_names import BONE_SEGMENTS, JOINT_INDEX, OPENXR_JOINT_COUNT

SEGMENT_MIN = 0.005  # [m] a tracked segment shorter than this is a broken frame
SEGMENT_MAX = 0.16   # [m] ... longer than this too
OUTLIER_SIGMAS = 4.0
OUTLIER_FLOOR = 0.003  # [m] never reject a frame for less than this (tracker noise is ~1-2 mm)
MIN_FRAMES = 20       # fewer inliers than this in the window: the window grows to all valid frames
WIDTH_SCALE_RANGE = (0.75, 1.25)

_PROX = np.array([s[0] for s in BONE_SEGMENTS])
_DIST = np.array([s[1] for s in BONE_SEGMENTS])
_J = JOINT_INDEX
_KNUCKLES = [_J[f.upper() + "_PROXIMAL"] for f in FINGERS4]
_CMC = _J["THUMB_METACARPAL"]
# Figures per frame: 16 lengths, then (x, y, z) of the index, ring, little knuckles and the CMC.
_N_LENGTHS = len(BONE_SEGMENTS)


@dataclass
class FitResult:
    """Measures fitted from tracker frames and how they were found.

    measures: HandMeasures at the tracked size. lengths (16,) [m]: median segment lengths (bone
    order of skeleton_names.BONE_NAMES). knuckles (4, 3), cmc (3,) [m]: medians in the palm
    frame (index, middle, ring, little; the middle is (palm_length, 0, 0) by construction).
    spread (16,) [m]: robust std (1.4826 MAD) of each length over the inliers. frames_valid,
    frames_window, frames_used: counts; window_s: time span [s] of the frames used.
    """

    measures: HandMeasures
    lengths: np.ndarray
    knuckles: np.ndarray
    cmc: np.ndarray
    spread: np.ndarray
    frames_total: int
    frames_valid: int
    frames_window: int
    frames_used: int
    window_s: float
    notes: list = field(default_factory=list)

    def summary(self) -> dict:
        """JSON-friendly figures (lengths in mm)."""
        mm = lambda a: np.round(np.asarray(a) * 1e3, 2).tolist()  # noqa: E731
        m = self.measures
        return dict(
            wrist_to_middle_tip_mm=round(hand_length(m) * 1e3, 1),
            palm_length_mm=round(m.palm_length * 1e3, 2), palm_width_mm=round(m.palm_width * 1e3, 2),
            bone_lengths_mm=mm(self.lengths), bone_length_spread_mm=mm(self.spread),
            knuckles_mm=mm(self.knuckles), thumb_cmc_mm=mm(self.cmc),
            frames_total=self.frames_total, frames_valid=self.frames_valid,
            frames_window=self.frames_window, frames_used=self.frames_used,
            window_s=round(self.window_s, 3), notes=list(self.notes))


def hand_length(m: HandMeasures) -> float:
    """Wrist joint to middle fingertip along the straight finger [m] (the 'hand size')."""
    return m.palm_length + sum(m.middle_lengths)


def palm_frame(joints: np.ndarray, side: float = 1.0) -> np.ndarray:
    """Rotation (3, 3) of the tracked palm frame (columns x, y, z) of joint positions (26, 3)."""
    x = joints[_J["MIDDLE_PROXIMAL"]] - joints[_J["WRIST"]]
    x = x / np.linalg.norm(x)
    z = side * np.cross(x, joints[_J["INDEX_PROXIMAL"]] - joints[_J["LITTLE_PROXIMAL"]])
    z = z / np.linalg.norm(z)
    return np.column_stack((x, np.cross(z, x), z))


def frame_figures(joints: np.ndarray, side: float = 1.0) -> np.ndarray | None:
    """The rigid figures of one frame (16 + 12,) [m] (module docstring), None if it is invalid.
    For a left hand (side -1) the palm-frame y is mirrored, so figures read as a right hand's."""
    p = np.asarray(joints, dtype=np.float64)[:, :3]
    if p.shape[0] != OPENXR_JOINT_COUNT or not np.all(np.isfinite(p)):
        return None
    lengths = np.linalg.norm(p[_DIST] - p[_PROX], axis=1)
    if lengths.min() < SEGMENT_MIN or lengths.max() > SEGMENT_MAX:
        return None
    cross = np.cross(p[_J["MIDDLE_PROXIMAL"]] - p[_J["WRIST"]], p[_J["INDEX_PROXIMAL"]] - p[_J["LITTLE_PROXIMAL"]])
    if np.linalg.norm(cross) < 1e-3 * lengths[0]:  # [m^2] as the adapter's check
        return None
    rot = palm_frame(p, side)
    local = (p[_KNUCKLES[:1] + _KNUCKLES[2:] + [_CMC]] - p[_J["WRIST"]]) @ rot
    local[:, 1] *= side
    return np.concatenate((lengths, local.reshape(-1)))


def robust_location(figures: np.ndarray):
    """Inlier mask (n,) of frames and the median (k,) and robust std (k,) of the inliers' figures."""
    med = np.median(figures, axis=0)
    sigma = 1.4826 * np.median(np.abs(figures - med), axis=0)
    limit = np.maximum(OUTLIER_SIGMAS * sigma, OUTLIER_FLOOR)
    inlier = np.all(np.abs(figures - med) <= limit, axis=1)
    kept = figures[inlier]
    med = np.median(kept, axis=0)
    return inlier, med, 1.4826 * np.median(np.abs(kept - med), axis=0)


def fit_measures(times_s, joints, seconds: float = 1.0, hand: str = "right",
                 base: HandMeasures | None = None) -> FitResult:
    """Measures of the tracked hand from frames `joints` (n, 26, 3|7) [m] captured at `times_s`
    (n,) [s], using the first `seconds` of valid frames (module docstring). `base` supplies what
    tracking cannot measure (default HandMeasures()). ValueError when no frame is valid."""
    if hand not in ("right", "left"):
        raise ValueError(f"hand must be 'right' or 'left', got {hand!r}")
    side = 1.0 if hand == "right" else -1.0
    base = HandMeasures() if base is None else base
    times = np.asarray(times_s, dtype=np.float64).reshape(-1)
    joints = np.asarray(joints, dtype=np.float64)
    if len(times) != len(joints):
        raise ValueError(f"{len(times)} times for {len(joints)} frames")
    figs, t_valid = [], []
    for t, j in zip(times, joints):
        f = frame_figures(j, side)
        if f is not None:
            figs.append(f)
            t_valid.append(t)
    if not figs:
        raise ValueError(f"none of the {len(joints)} tracker frames is valid (26 finite joints, "
                         f"segments {SEGMENT_MIN * 1e3:.0f}-{SEGMENT_MAX * 1e3:.0f} mm)")
    figs, t_valid = np.array(figs), np.array(t_valid)
    notes = []
    # the window runs to the first frame at or past `seconds` after the first valid one (>= 1 s)
    later = np.nonzero(t_valid >= t_valid[0] + seconds)[0]
    window = t_valid <= (t_valid[later[0]] if len(later) else np.inf)
    inlier, med, sigma = robust_location(figs[window])
    if inlier.sum() < MIN_FRAMES and window.sum() < len(figs):
        notes.append(f"only {int(inlier.sum())} good frames in the first {seconds} s: used all frames")
        window = np.ones(len(figs), dtype=bool)
        inlier, med, sigma = robust_location(figs[window])
    used_t = t_valid[window][inlier]
    span_s = float(used_t[-1] - used_t[0]) if len(used_t) else 0.0
    if span_s < seconds:
        notes.append(f"the frames used span {span_s:.2f} s, less than the {seconds} s asked for")
    # Noise across a segment lengthens it on average: |L + n|^2 = L^2 + |n_perp|^2 + ..., and the
    # spread of a length is the noise along it; with isotropic noise the two perpendicular parts
    # add 2 spread^2, so the unbiased length is sqrt(median^2 - 2 spread^2).
    spread = sigma[:_N_LENGTHS]
    lengths = np.sqrt(np.maximum(med[:_N_LENGTHS] ** 2 - 2.0 * spread ** 2, 0.25 * med[:_N_LENGTHS] ** 2))
    local = med[_N_LENGTHS:].reshape(4, 3)
    knuckles = np.vstack([local[0], [lengths[0], 0.0, 0.0], local[1], local[2]])
    m = measures_from(lengths, knuckles, local[3], base, notes)
    return FitResult(m, lengths, knuckles, local[3], spread, len(joints), len(figs),
                     int(window.sum()), int(inlier.sum()), span_s, notes)


def _clip(name, values, notes):
    lo, hi = _LAYOUT_RANGES[name]
    out = tuple(float(np.clip(v, a, b)) for v, a, b in zip(values, lo, hi))
    if out != tuple(float(v) for v in values):
        notes.append(f"{name} {np.round(values, 3).tolist()} clipped to its range: {np.round(out, 3).tolist()}")
    return out


def measures_from(lengths, knuckles, cmc, base: HandMeasures, notes=None) -> HandMeasures:
    """HandMeasures from tracked lengths (16,) [m], knuckles (4, 3) and CMC (3,) in the palm frame
    [m]; widths and thickness from `base`, scaled by the hand-length ratio (module docstring)."""
    notes = [] if notes is None else notes
    lengths = np.asarray(lengths, dtype=np.float64)
    palm = float(lengths[0])
    digits = {f: tuple(float(v) for v in lengths[1 + 3 * i: 4 + 3 * i])
              for i, f in enumerate(("thumb",) + FINGERS4)}
    ratio = (palm + sum(digits["middle"])) / hand_length(base)
    k = float(np.clip(ratio, *WIDTH_SCALE_RANGE))
    widths = {f + "_width": base.finger_width(f) * k for f in ("thumb",) + FINGERS4}
    thickness = base.palm_thickness * k
    y = knuckles[:, 1]
    span = float(y[0] - y[3])
    gaps = np.array([y[0] - y[1], y[1] - y[2], y[2] - y[3]]) * 3.0 / span
    gaps = _clip("knuckle_gaps", gaps, notes)
    gaps = tuple(g * 3.0 / sum(gaps) for g in gaps)
    recess = _clip("knuckle_recess", [1.0 - knuckles[i, 0] / palm for i in (0, 2, 3)], notes)
    palm_width = span + 0.5 * (widths["index_width"] + widths["little_width"])
    m = replace(base, palm_length=palm, palm_width=palm_width, palm_thickness=thickness,
                knuckle_recess=recess, knuckle_gaps=gaps,
                **{f + "_lengths": v for f, v in digits.items()}, **widths)
    s = knuckle_span(m) / 3.0
    cmc_frac = _clip("thumb_cmc", [cmc[0] / palm, cmc[1] / s, cmc[2] / thickness], notes)
    return replace(m, thumb_cmc=cmc_frac)
