"""The two-hand skeleton: 21 keypoints per hand, their bones and colours.

Keypoint order per hand (the widely used 21-point hand layout: wrist, then
each finger from the palm outwards, thumb first)::

     0 wrist
     1 thumb_cmc   2 thumb_mcp   3 thumb_ip    4 thumb_tip
     5 index_mcp   6 index_pip   7 index_dip   8 index_tip
     9 middle_mcp 10 middle_pip 11 middle_dip 12 middle_tip
    13 ring_mcp   14 ring_pip   15 ring_dip   16 ring_tip
    17 pinky_mcp  18 pinky_pip  19 pinky_dip  20 pinky_tip

A trajectory holds both hands: hand axis 0 = left, 1 = right, so skeleton
point ``21 * hand + k`` is keypoint ``k`` of that hand (names ``left_wrist``,
``right_index_tip``, ...).

Bones: wrist → first point of each finger (the metacarpals), then along each
finger: 20 per hand. The skeleton is two trees, one per hand.

MANO's own 16 joints come in another order (wrist; index, middle, pinky,
ring, thumb, three joints each) and have no fingertips;
:data:`MANO_TO_KEYPOINTS` reorders them after the five fingertip vertices
(:data:`FINGERTIP_VERTICES`) are appended.
"""

from __future__ import annotations

__all__ = [
    "HANDS",
    "FINGERS",
    "KEYPOINT_NAMES",
    "NUM_KEYPOINTS",
    "POINT_NAMES",
    "HAND_BONES",
    "BONES",
    "EDGES",
    "GROUPS",
    "COLORS",
    "TIPS",
    "MCPS",
    "PALM",
    "FINGER_CHAINS",
    "FINGERTIP_VERTICES",
    "MANO_JOINT_NAMES",
    "MANO_TO_KEYPOINTS",
    "point_name",
]

HANDS: tuple[str, str] = ("left", "right")
FINGERS: tuple[str, ...] = ("thumb", "index", "middle", "ring", "pinky")

KEYPOINT_NAMES: tuple[str, ...] = (
    "wrist",
    "thumb_cmc",
    "thumb_mcp",
    "thumb_ip",
    "thumb_tip",
    "index_mcp",
    "index_pip",
    "index_dip",
    "index_tip",
    "middle_mcp",
    "middle_pip",
    "middle_dip",
    "middle_tip",
    "ring_mcp",
    "ring_pip",
    "ring_dip",
    "ring_tip",
    "pinky_mcp",
    "pinky_pip",
    "pinky_dip",
    "pinky_tip",
)
NUM_KEYPOINTS = len(KEYPOINT_NAMES)  # 21

#: Per finger, its four keypoint indices from the palm outwards.
FINGER_CHAINS: dict[str, tuple[int, int, int, int]] = {
    f: tuple(range(1 + 4 * i, 5 + 4 * i)) for i, f in enumerate(FINGERS)
}
#: Keypoint indices of the fingertips (thumb .. pinky) and of the four finger MCPs.
TIPS: tuple[int, ...] = tuple(c[-1] for c in FINGER_CHAINS.values())
MCPS: tuple[int, ...] = tuple(FINGER_CHAINS[f][0] for f in FINGERS[1:])
#: Keypoints whose mean is the palm centre (where the open/close indicator is drawn).
PALM: tuple[int, ...] = (0,) + MCPS

#: (parent, child) keypoint indices of one hand: metacarpals, then the finger bones.
HAND_BONES: tuple[tuple[int, int], ...] = tuple(
    pair for chain in FINGER_CHAINS.values() for pair in zip((0,) + chain[:-1], chain)
)


def point_name(hand: str, k: int) -> str:
    """Skeleton point name of keypoint ``k`` of ``hand`` ("left"/"right")."""
    return f"{hand}_{KEYPOINT_NAMES[k]}"


POINT_NAMES: tuple[str, ...] = tuple(point_name(h, k) for h in HANDS for k in range(NUM_KEYPOINTS))
BONES: tuple[tuple[str, str], ...] = tuple((point_name(h, a), point_name(h, b)) for h in HANDS for a, b in HAND_BONES)
EDGES: tuple[tuple[str, str], ...] = BONES

#: Colour groups: one per finger and hand, plus each wrist. An edge takes its
#: child's colour, so a metacarpal has its finger's colour.
GROUPS: dict[str, tuple[str, ...]] = {}
for _h in HANDS:
    GROUPS[f"{_h}_wrist"] = (point_name(_h, 0),)
    for _f, _chain in FINGER_CHAINS.items():
        GROUPS[f"{_h}_{_f}"] = tuple(point_name(_h, k) for k in _chain)

#: Left hand in warm hues, right hand in cool hues; within a hand the five
#: fingers differ in hue too. All saturated, and the two hands' sets are far
#: apart in chroma so they stay distinct after 4:2:0 chroma subsampling.
COLORS: dict[str, tuple[int, int, int]] = {
    "left_wrist": (255, 235, 200),
    "left_thumb": (255, 40, 40),
    "left_index": (255, 130, 0),
    "left_middle": (255, 210, 0),
    "left_ring": (255, 60, 160),
    "left_pinky": (200, 60, 255),
    "right_wrist": (200, 235, 255),
    "right_thumb": (0, 90, 255),
    "right_index": (0, 200, 255),
    "right_middle": (0, 255, 170),
    "right_ring": (120, 255, 40),
    "right_pinky": (120, 120, 255),
}

# ---- MANO ------------------------------------------------------------------------

#: smplx.MANO's 16 joints, in the order of the model's kinematic tree.
MANO_JOINT_NAMES: tuple[str, ...] = (
    "wrist",
    "index_mcp",
    "index_pip",
    "index_dip",
    "middle_mcp",
    "middle_pip",
    "middle_dip",
    "pinky_mcp",
    "pinky_pip",
    "pinky_dip",
    "ring_mcp",
    "ring_pip",
    "ring_dip",
    "thumb_cmc",
    "thumb_mcp",
    "thumb_ip",
)

#: MANO mesh vertices used as fingertips (the ``mano`` entry of smplx's
#: ``vertex_ids.py``), appended after the 16 joints as indices 16..20.
FINGERTIP_VERTICES: dict[str, int] = {"thumb": 744, "index": 320, "middle": 443, "ring": 554, "pinky": 671}

_MANO_PLUS_TIPS = MANO_JOINT_NAMES + tuple(f"{f}_tip" for f in FINGERTIP_VERTICES)
#: ``keypoints = mano_joints_plus_tips[:, MANO_TO_KEYPOINTS]`` gives the 21-keypoint order.
MANO_TO_KEYPOINTS: tuple[int, ...] = tuple(_MANO_PLUS_TIPS.index(n) for n in KEYPOINT_NAMES)
