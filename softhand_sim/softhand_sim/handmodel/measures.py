"""Hand measures: the small set of numbers the parametric hand is built from.

All lengths in metres. Defaults describe an adult hand of about 19 cm from the wrist joint to the
middle fingertip (palm 9.0 cm + middle finger 10.0 cm) and 8.5 cm palm width at the knuckles.
Finger bone lengths are joint-to-joint; a distal bone runs from its DIP (thumb: IP) joint to the
fingertip skin, as the tracker's DISTAL -> TIP segment does.
"""
import hashlib
import json
from dataclasses import asdict, dataclass, fields

FINGERS4 = ("index", "middle", "ring", "little")
# Admissible ranges (min per entry, max per entry) of the three-number layout measures.
_LAYOUT_RANGES = {
    "knuckle_recess": ((-0.05, -0.05, 0.0), (0.15, 0.15, 0.30)),
    "knuckle_gaps": ((0.6, 0.6, 0.6), (1.5, 1.5, 1.5)),
    "thumb_cmc": ((-0.15, 0.0, -0.8), (0.5, 1.8, 0.2)),
}


@dataclass(frozen=True)
class HandMeasures:
    """Build parameters of the hand [m unless stated]."""

    palm_length: float = 0.090  # wrist joint -> middle MCP joint
    palm_width: float = 0.085  # across the knuckles, skin to skin
    palm_thickness: float = 0.028  # dorsal to palmar skin at the mid palm
    # proximal, intermediate, distal (joint -> joint; distal: DIP -> fingertip)
    index_lengths: tuple = (0.043, 0.025, 0.022)
    middle_lengths: tuple = (0.047, 0.029, 0.024)
    ring_lengths: tuple = (0.044, 0.027, 0.023)
    little_lengths: tuple = (0.034, 0.020, 0.020)
    thumb_lengths: tuple = (0.044, 0.032, 0.028)  # metacarpal, proximal, distal (IP -> tip)
    # finger diameter at the proximal phalanx; the finger tapers toward the tip
    index_width: float = 0.0185
    middle_width: float = 0.0190
    ring_width: float = 0.0178
    little_width: float = 0.0158
    thumb_width: float = 0.0210
    finger_spread_deg: float = 5.0  # angle between neighbouring finger axes at rest [deg]
    # Knuckle (MCP) layout. knuckle_recess: how far the index, ring and little knuckles lie
    # proximal to the middle knuckle, as fractions of palm_length (the arched knuckle row).
    # knuckle_gaps: the index-middle, middle-ring and ring-little gaps across the palm in units
    # of their mean, a third of the index-to-little span (palm_width minus half the index and
    # little widths); they sum to 3.
    knuckle_recess: tuple = (0.045, 0.045, 0.155)
    knuckle_gaps: tuple = (1.0, 1.0, 1.0)
    # Thumb CMC joint in the palm frame: x as a fraction of palm_length, y (toward the thumb) as
    # a fraction of the mean knuckle gap (span / 3), z (dorsal) as a fraction of palm_thickness.
    thumb_cmc: tuple = (0.25, 0.75, -0.22)

    def __post_init__(self):
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name.endswith("_lengths"):
                if len(value) != 3:
                    raise ValueError(f"hand measure {f.name!r} needs 3 bone lengths, got {value!r}")
                object.__setattr__(self, f.name, tuple(float(v) for v in value))
                bad = [v for v in value if not 0.005 <= v <= 0.15]
            elif f.name in _LAYOUT_RANGES:
                lo, hi = _LAYOUT_RANGES[f.name]
                if len(value) != 3:
                    raise ValueError(f"hand measure {f.name!r} needs 3 numbers, got {value!r}")
                object.__setattr__(self, f.name, tuple(float(v) for v in value))
                bad = [v for v, a, b in zip(value, lo, hi) if not a <= v <= b]
                if f.name == "knuckle_gaps" and not bad and abs(sum(value) - 3.0) > 1e-6:
                    raise ValueError(f"hand measure 'knuckle_gaps' must sum to 3, got {value!r}")
            elif f.name == "finger_spread_deg":
                bad = [value] if not 0.0 <= value <= 20.0 else []
            else:
                bad = [value] if not 0.005 <= value <= 0.3 else []
            if bad:
                raise ValueError(f"hand measure {f.name!r} = {value!r} is out of its range")

    def finger_lengths(self, finger):
        """The three bone lengths of `finger` (thumb, index, middle, ring, little)."""
        try:
            return getattr(self, finger + "_lengths")
        except AttributeError:
            raise ValueError(f"unknown finger {finger!r}") from None

    def finger_width(self, finger):
        return getattr(self, finger + "_width")

    def to_dict(self):
        d = asdict(self)
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in d.items()}

    @classmethod
    def from_dict(cls, d):
        known = {f.name for f in fields(cls)}
        unknown = set(d) - known
        if unknown:
            raise ValueError(f"unknown hand measure(s): {sorted(unknown)}")
        return cls(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in d.items()})

    def digest(self):
        """Short stable hash of the measures (for the cache key)."""
        text = json.dumps(self.to_dict(), sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:16]


def as_measures(measures):
    """None -> defaults; dict -> validated HandMeasures; HandMeasures passes through."""
    if measures is None:
        return HandMeasures()
    if isinstance(measures, HandMeasures):
        return measures
    if isinstance(measures, dict):
        return HandMeasures.from_dict(measures)
    raise TypeError(f"measures must be None, a dict or HandMeasures, got {type(measures).__name__}")


def scale_measures(measures, factor, **overrides):
    """`measures` with every length and width times `factor` (ratios, angles and the layout
    fractions kept), then the named `overrides` [m] applied."""
    m = as_measures(measures)
    scaled = {}
    for f in fields(m):
        v = getattr(m, f.name)
        if f.name.endswith("_lengths"):
            scaled[f.name] = tuple(factor * x for x in v)
        elif f.name.endswith(("_width", "_length", "_thickness")):
            scaled[f.name] = factor * v
    scaled.update(overrides)
    return HandMeasures.from_dict({**m.to_dict(), **scaled})


MEASURES_FILE_KEY = "hand_measures"


def write_measures_file(path, measures, comment=""):
    """Write `measures` as YAML: {hand_measures: {name: value}} [m, deg], `comment` lines on top."""
    import yaml
    head = "".join(f"# {line}\n" for line in comment.splitlines())
    body = yaml.safe_dump({MEASURES_FILE_KEY: as_measures(measures).to_dict()}, sort_keys=False)
    with open(path, "w") as f:
        f.write(head + body)


def read_measures_file(path):
    """HandMeasures from a file written by write_measures_file (or a bare mapping of measures);
    measures it does not name keep their defaults. ValueError naming the file when it is bad."""
    import yaml
    try:
        with open(path) as f:
            data = yaml.safe_load(f)
    except (OSError, yaml.YAMLError) as exc:
        raise ValueError(f"cannot read hand measures file {path}: {exc}") from None
    if isinstance(data, dict) and MEASURES_FILE_KEY in data:
        data = data[MEASURES_FILE_KEY]
    if not isinstance(data, dict):
        raise ValueError(f"hand measures file {path} holds no mapping of measures")
    try:
        return HandMeasures.from_dict(data)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"hand measures file {path}: {exc}") from None
