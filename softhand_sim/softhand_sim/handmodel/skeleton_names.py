"""Names and orders fixed by the public contract (docs/INTERFACE.md): bones, tracker joints, segments."""

BONE_NAMES = (
    "palm",
    "thumb_metacarpal", "thumb_proximal", "thumb_distal",
    "index_proximal", "index_intermediate", "index_distal",
    "middle_proximal", "middle_intermediate", "middle_distal",
    "ring_proximal", "ring_intermediate", "ring_distal",
    "little_proximal", "little_intermediate", "little_distal",
)
BONE_COUNT = len(BONE_NAMES)
FINGER_NAMES = ("thumb", "index", "middle", "ring", "little")

# OpenXR XR_EXT_hand_tracking joint order (26).
OPENXR_JOINT_NAMES = (
    "PALM", "WRIST",
    "THUMB_METACARPAL", "THUMB_PROXIMAL", "THUMB_DISTAL", "THUMB_TIP",
    "INDEX_METACARPAL", "INDEX_PROXIMAL", "INDEX_INTERMEDIATE", "INDEX_DISTAL", "INDEX_TIP",
    "MIDDLE_METACARPAL", "MIDDLE_PROXIMAL", "MIDDLE_INTERMEDIATE", "MIDDLE_DISTAL", "MIDDLE_TIP",
    "RING_METACARPAL", "RING_PROXIMAL", "RING_INTERMEDIATE", "RING_DISTAL", "RING_TIP",
    "LITTLE_METACARPAL", "LITTLE_PROXIMAL", "LITTLE_INTERMEDIATE", "LITTLE_DISTAL", "LITTLE_TIP",
)
OPENXR_JOINT_COUNT = len(OPENXR_JOINT_NAMES)
JOINT_INDEX = {name: i for i, name in enumerate(OPENXR_JOINT_NAMES)}


def _segment(a, b):
    return (JOINT_INDEX[a], JOINT_INDEX[b])


# Bone i is tracked by the segment BONE_SEGMENTS[i] = (proximal joint, distal joint).
BONE_SEGMENTS = (
    _segment("WRIST", "MIDDLE_PROXIMAL"),
    _segment("THUMB_METACARPAL", "THUMB_PROXIMAL"),
    _segment("THUMB_PROXIMAL", "THUMB_DISTAL"),
    _segment("THUMB_DISTAL", "THUMB_TIP"),
) + tuple(
    seg
    for f in ("INDEX", "MIDDLE", "RING", "LITTLE")
    for seg in (
        _segment(f + "_PROXIMAL", f + "_INTERMEDIATE"),
        _segment(f + "_INTERMEDIATE", f + "_DISTAL"),
        _segment(f + "_DISTAL", f + "_TIP"),
    )
)

# Parent bone of each bone in the skeleton tree (-1 for the palm).
BONE_PARENT = (-1, 0, 1, 2, 0, 4, 5, 0, 7, 8, 0, 10, 11, 0, 13, 14)
