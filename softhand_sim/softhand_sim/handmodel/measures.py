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

    def __post_init__(self):
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name.endswith("_lengths"):
                if len(value) != 3:
                    raise ValueError(f"hand measure {f.name!r} needs 3 bone lengths, got {value!r}")
                object.__setattr__(self, f.name, tuple(float(v) for v in value))
                bad = [v for v in value if not 0.005 <= v <= 0.15]
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
