"""Human-hand episodes in the toy world: a MANO-layout hand reaches for the ball and picks it up, or pushes it.

The hand is a *keypoint* embodiment (the ``mano`` plugin: 21 points per hand, two hands, NaN for a hand that
is absent). Its keypoints come from the plugin's procedural hand
(:func:`oscar_embodiments.mano.synthetic.hand_keypoints`: a curl in [0, 1] bends every joint), placed in the
world by a wrist position and a fixed orientation per episode; the trajectory is the plugin's own
(:func:`oscar_embodiments.mano.trajectory_from_keypoints`), so the skeleton video of a hand episode is the
plugin's rendering of exactly the points the RGB capsules are drawn along. One hand per episode (left or
right, drawn per episode); the other hand's points are NaN and nothing of it is drawn.

Units: metres in the world (z up, floor z = 0), the hand frame of :mod:`oscar_embodiments.mano.synthetic`
(x towards the fingers, y towards the thumb for a right hand, z out of the back of the hand).

**When a hand is closed** (:func:`hand_closed`): the distance between the thumb tip and the index tip is
below :data:`PINCH_CLOSED_M`. The hand's end-effector (:func:`pinch_point`) is the midpoint of those two tips.
The ball then follows the hand by the gripper's rule (:func:`~oscar_core.toyworld.motion.carry_object`):
it attaches on a frame where the hand *closes* while the pinch point is within
:data:`~oscar_core.toyworld.motion.GRAB_RADII` ball radii of its centre, keeps its offset while the hand stays
closed, and drops to the floor below where it was when the hand opens.

**Push** (:func:`push_object`): the contact point is the mean of the four finger tips (index to pinky). On a
frame where the contact point is lower than :data:`PUSH_MAX_HEIGHT_RADII` ball radii above the floor and
closer than ``R + PUSH_CONTACT_M`` to the ball's centre horizontally, the ball slides along the floor
(z = R) to exactly that distance from the contact point, away from it; otherwise it stays.
"""

from __future__ import annotations

import colorsys

import numpy as np

from ..plugin.embodiment import Embodiment
from .motion import GRAB_RADII, Motion, ToyWorldError, carry_object, is_hand, min_jerk
from .scene import Scene, sample_scene

__all__ = [
    "HAND_SOURCE",
    "HAND_MIN_FRAMES",
    "PINCH_CLOSED_M",
    "BALL_RADIUS_M",
    "HAND_SCALE_M",
    "PUSH_CONTACT_M",
    "PUSH_MAX_HEIGHT_RADII",
    "pinch_point",
    "pinch_distance",
    "hand_closed",
    "hand_carry",
    "push_object",
    "hand_link_radii",
    "sample_hand_motion",
    "sample_hand_scene",
]

#: The ``source`` of hand clips in a clip set (robots' clips have ``"toyworld"``): training mixes them by it.
HAND_SOURCE = "toyworld_hand"
#: A hand is closed when its thumb tip and index tip are closer than this, metres. The procedural hand's
#: pinch distance is 0.073 m open (curl 0), 0.062 m at curl 0.1, 0.021 m at the grasp curl (0.6), and below
#: 0.045 m for curls 0.22-0.78 (measured on :func:`~oscar_embodiments.mano.synthetic.hand_keypoints`).
PINCH_CLOSED_M = 0.045
#: Curls (0 = flat hand, 1 = fist) of the open hand, of the grasp, and the most a pushing hand curls.
OPEN_CURL = 0.0
GRASP_CURL = 0.6
PUSH_MAX_CURL = 0.1
#: The ball's radius, metres (a ball a hand holds between thumb and index finger).
BALL_RADIUS_M = 0.02
#: The hand's workspace size, metres: what a robot's reach is to the scene (floor tiles, fog, ``reach_m``).
HAND_SCALE_M = 0.4
#: Push: the ball is kept this far plus its radius from the contact point (about a fingertip's radius), metres.
PUSH_CONTACT_M = 0.012
#: Push: the contact point touches the ball only below this height, in ball radii above the floor.
PUSH_MAX_HEIGHT_RADII = 2.0
#: The fewest frames a hand episode has (its pick_place has seven keyframes).
HAND_MIN_FRAMES = 9
#: Capsule radii, metres: the metacarpals (palm) and the finger bones.
PALM_RADIUS_M = 0.016
FINGER_RADIUS_M = 0.011

_PUSH_TIPS = (8, 12, 16, 20)  # index, middle, ring, pinky tips (topology.KEYPOINT_NAMES)


def pinch_point(kp: np.ndarray) -> np.ndarray:
    """(..., 21, 3) keypoints of one hand → (..., 3) midpoint of the thumb tip and the index tip, metres."""
    return (kp[..., 4, :] + kp[..., 8, :]) / 2


def pinch_distance(kp: np.ndarray) -> np.ndarray:
    """(..., 21, 3) keypoints of one hand → (...) thumb tip to index tip distance, metres."""
    return np.linalg.norm(kp[..., 4, :] - kp[..., 8, :], axis=-1)


def hand_closed(kp: np.ndarray) -> np.ndarray:
    """(..., 21, 3) keypoints of one hand → (...) bool: closed when the pinch distance < :data:`PINCH_CLOSED_M`."""
    return pinch_distance(kp) < PINCH_CLOSED_M


def hand_carry(kp: np.ndarray, start: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """The gripper's carry rule (:func:`~oscar_core.toyworld.motion.carry_object`) for a hand.

    kp: (T, 21, 3) keypoints of the hand, metres; start: (3,) the ball's centre at frame 0 (z = radius).
    The end-effector is :func:`pinch_point`, closed is :func:`hand_closed`, the grab distance
    :data:`~oscar_core.toyworld.motion.GRAB_RADII` ``radius``. Returns positions (T, 3) metres, attached (T,).
    """
    openness = np.where(hand_closed(kp), 0.0, 1.0)
    return carry_object(pinch_point(kp), openness, start, radius, grab_distance=GRAB_RADII * radius)


def push_object(contact: np.ndarray, start: np.ndarray, radius: float) -> np.ndarray:
    """Ball centres (T, 3) under the push rule of the module docstring.

    contact: (T, 3) the hand's contact point, metres; start: (3,) the ball's centre at frame 0 (z = radius).
    Between two frames the contact point moves in straight sub-steps of at most a quarter of ``radius`` +
    :data:`PUSH_CONTACT_M`, so a fast hand cannot pass through the ball between frames.
    """
    reach = radius + PUSH_CONTACT_M
    c_all = np.asarray(contact, dtype=np.float64)
    p = np.asarray(start, dtype=np.float64).copy()
    out = np.empty((len(c_all), 3))
    for t in range(len(c_all)):
        prev = c_all[max(t - 1, 0)]
        n = max(1, int(np.ceil(np.linalg.norm(c_all[t] - prev) / (0.25 * reach))))
        for c in prev + (c_all[t] - prev) * (np.arange(1, n + 1) / n)[:, None]:
            d = p[:2] - c[:2]
            dist = float(np.linalg.norm(d))
            if c[2] < PUSH_MAX_HEIGHT_RADII * radius and dist < reach:
                direction = d / dist if dist > 1e-9 else np.array([1.0, 0.0])
                p = np.array([c[0] + reach * direction[0], c[1] + reach * direction[1], radius])
        out[t] = p
    return out


def hand_link_radii(n_edges: int) -> np.ndarray:
    """(E,) capsule radii of the mano skeleton's edges, metres: :data:`PALM_RADIUS_M` for the five bones that
    leave a wrist, :data:`FINGER_RADIUS_M` for the others (edges in ``topology.EDGES`` order)."""
    from oscar_embodiments.mano.topology import EDGES

    if n_edges != len(EDGES):
        raise ToyWorldError(f"toyworld hand: expected the mano skeleton's {len(EDGES)} edges, found {n_edges}")
    return np.array([PALM_RADIUS_M if a.endswith("_wrist") else FINGER_RADIUS_M for a, _ in EDGES])


def _rotation(yaw: float, pitch: float) -> np.ndarray:
    """(3, 3) hand frame → world: fingers along ``yaw`` tilted ``pitch`` radians down, palm facing down."""
    cy, sy, cp, sp = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch)
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1.0]])
    Ry = np.array([[cp, 0, sp], [0, 1.0, 0], [-sp, 0, cp]])
    return Rz @ Ry


def _pose(curl: float, side: str, R: np.ndarray, wrist: np.ndarray) -> np.ndarray:
    from oscar_embodiments.mano.synthetic import hand_keypoints

    return hand_keypoints(curl, side=side) @ R.T + wrist


def _points_at(curls: np.ndarray, wrists: np.ndarray, side: str, R: np.ndarray) -> np.ndarray:
    return np.stack([_pose(float(c), side, R, w) for c, w in zip(curls, wrists)])


def sample_hand_motion(emb: Embodiment, rng: np.random.Generator, frames: int, fps: float = 10.0) -> Motion:
    """A hand episode of ``frames`` frames (>= 9): pick-and-place (70 %) or push (30 %).

    Pick-and-place: the open hand comes down over the ball, closes (curl 0 → 0.6) with its pinch point held at
    the ball's centre, lifts, carries it 0.10–0.22 m, lowers it, opens and rises; its keyframes are the pinch
    point and the curl, and the wrist follows from them. Push: the open hand (curl 0–0.1, so never closed;
    fingers 50–65° down) lowers its finger tips to the floor 3–4 ball radii behind the ball and
    sweeps 6–10 radii through it, then rises; its keyframes are wrist positions. Keyframes are joined by
    minimum-jerk segments (:func:`~oscar_core.toyworld.motion.min_jerk`); the hand's orientation is fixed per
    episode, facing away from the arm's shoulder at the origin. Returns a :class:`Motion` whose ``points`` are the
    mano skeleton's 42 points (the absent hand NaN) and ``ee`` the pinch point.
    """
    from oscar_embodiments.mano.convert import trajectory_from_keypoints
    from oscar_embodiments.mano.synthetic import hand_keypoints
    from oscar_embodiments.mano.topology import NUM_KEYPOINTS

    if not is_hand(emb):
        raise ToyWorldError(f"toyworld hand: expected the mano two-hand skeleton, found embodiment {emb.name!r}")
    if frames < HAND_MIN_FRAMES:
        raise ToyWorldError(
            f"toyworld: --frames: expected at least {HAND_MIN_FRAMES} frames for a hand episode, found {frames}"
        )
    T = frames
    Rb = BALL_RADIUS_M
    side = "right" if rng.uniform() < 0.5 else "left"
    kind = "pick_place" if rng.uniform() < 0.7 else "push"
    ang = rng.uniform(-1.0, 1.0)  # radians around +x: where the ball lies, seen from the shoulder
    dist = rng.uniform(0.25, 0.4)
    ball0 = np.array([dist * np.cos(ang), dist * np.sin(ang), Rb])
    yaw = ang + rng.uniform(-0.3, 0.3)
    if kind == "pick_place":
        R = _rotation(yaw, np.deg2rad(rng.uniform(20, 40)))
        place_dir = rng.uniform(-np.pi, np.pi)
        place = ball0 + rng.uniform(0.10, 0.22) * np.array([np.cos(place_dir), np.sin(place_dir), 0.0])
        lift_z = rng.uniform(0.10, 0.18)
        start = ball0 + [rng.uniform(-0.08, 0.0), rng.uniform(-0.08, 0.08), rng.uniform(0.12, 0.22)]
        end = place + [rng.uniform(-0.08, 0.0), rng.uniform(-0.08, 0.08), rng.uniform(0.12, 0.22)]
        a = int(round((T - 1) * rng.uniform(0.28, 0.38)))
        hold = a + max(1, int(round(0.12 * (T - 1))))
        b = int(round((T - 1) * rng.uniform(0.70, 0.78)))
        b = min(max(b, hold + 2), T - 2)
        release = min(b + max(1, int(round(0.1 * (T - 1)))), T - 1)
        lift = (ball0 + place) / 2 + [0, 0, lift_z]
        times = np.array([0, a, hold, (hold + b) // 2, b, release, T - 1])
        targets = np.stack([start, ball0, ball0, lift, place, place, end])  # the pinch point at each key
        curls = np.array([OPEN_CURL, OPEN_CURL, GRASP_CURL, GRASP_CURL, GRASP_CURL, OPEN_CURL, OPEN_CURL])
        times, keep = np.unique(times, return_index=True)
        path = min_jerk(np.concatenate([targets, curls[:, None]], axis=1)[keep], times, T)
        pinch_local = np.stack([R @ pinch_point(hand_keypoints(float(c), side=side)) for c in path[:, 3]])
        wrists, curl_t = path[:, :3] - pinch_local, path[:, 3]
    else:
        R = _rotation(yaw, np.deg2rad(rng.uniform(50, 65)))
        curl = rng.uniform(OPEN_CURL, PUSH_MAX_CURL)
        local = hand_keypoints(curl, side=side) @ R.T
        contact = local[list(_PUSH_TIPS)].mean(0)
        lift_by = 0.2 * Rb - local[:, 2].min()  # the lowest point 0.2 radii above the floor
        fwd = np.array([np.cos(yaw), np.sin(yaw), 0.0])
        c0 = ball0 - rng.uniform(3.0, 4.0) * Rb * fwd
        c1 = c0 + rng.uniform(6.0, 10.0) * Rb * fwd
        w0 = np.array([c0[0] - contact[0], c0[1] - contact[1], lift_by])
        w1 = np.array([c1[0] - contact[0], c1[1] - contact[1], lift_by])
        up = np.array([0, 0, rng.uniform(0.10, 0.18)])
        a = int(round((T - 1) * rng.uniform(0.2, 0.3)))
        b = int(round((T - 1) * rng.uniform(0.7, 0.8)))
        b = min(max(b, a + 2), T - 2)
        times, keep = np.unique(np.array([0, a, b, T - 1]), return_index=True)
        wrists = min_jerk(np.stack([w0 + up, w0, w1, w1 + up])[keep], times, T)
        curl_t = np.full(T, curl)
    kp = _points_at(curl_t, wrists, side, R)  # (T, 21, 3)
    ee = pinch_point(kp)
    # the gripper's rule on the pose's closed state; a pushing hand never closes, so only the push moves its ball
    obj, attached = hand_carry(kp, ball0, Rb)
    if kind == "push":
        obj = push_object(kp[:, list(_PUSH_TIPS)].mean(1), ball0, Rb)
    traj = trajectory_from_keypoints(kp, fps, hand=side, source=f"<toyworld {emb.name}>")
    points = traj.keypoints.reshape(T, 2 * NUM_KEYPOINTS, 3)
    return Motion(
        traj,
        kind,
        points,
        ee,
        obj,
        attached,
        Rb,
        HAND_SCALE_M,
        link_radii=hand_link_radii(len(emb.edges)),
        marker=False,
    )


def sample_hand_scene(rng: np.random.Generator, n_edges: int, scale: float) -> Scene:
    """:func:`~oscar_core.toyworld.scene.sample_scene` with every edge in one skin tone drawn per episode.

    Skin: hue 10–28°, saturation 0.2–0.4, value 0.45–0.95: at least 21° from the ball's hue (49°) and below
    the ball locator's saturation of 0.5 (:mod:`oscar_core.toyworld.locate`: hue within 18°, saturation
    >= 0.5), so a hand is not read as the yellow ball.
    """
    scene = sample_scene(rng, n_edges, scale)
    skin = np.array(colorsys.hsv_to_rgb(rng.uniform(10, 28) / 360.0, rng.uniform(0.2, 0.4), rng.uniform(0.45, 0.95)))
    return Scene(
        scene.floor_colors,
        scene.tile,
        scene.noise_seed,
        scene.sky_top,
        scene.sky_bottom,
        scene.light,
        np.repeat(skin[None], n_edges, 0),
        scene.fog,
    )
