"""Random reaching and pick-and-place motions for any kinematic-tree embodiment, and the object they move.

Joint values are drawn inside the URDF limits (``Embodiment.tree.limits``,
shrunk by 5 %; unlimited joints use [-pi, pi]) and joined by minimum-jerk
segments, so every frame is inside the limits and velocity is zero at each
keyframe. Keyframes are chosen from a batch of random configurations by their
forward kinematics (no IK): the grasp and place poses put the end-effector
just above the floor, the "lift" pose well above it, and no pose puts a
skeleton point under the floor.

The object rule (:func:`carry_object`): the object is a ball of radius R
resting on the floor (z = R). It attaches to the end-effector on a frame
where the gripper *closes* (openness drops below 0.5) while the end-effector
is within ``grab_distance`` of the ball's centre, then keeps its offset from
the end-effector while the gripper stays closed; when the gripper opens it
drops to the floor below where it was (z = R, same x, y) on that frame.

Pushing (``carry_object(..., push_contact=c)``, off by default; :data:`PUSH_CONTACT_RADII` is the toy world's
contact distance): the end-effector is a solid sphere and the ball stays on the floor. On a frame where the gripper
is open and holds nothing, the end-effector is moved from the previous frame's position in straight sub-steps of
at most c / 4; after each sub-step that brings it closer to the ball's centre and closer than c (3-D), the ball
slides along the floor (z = R) away from it, along the horizontal line from the end-effector's foot to the ball's
centre (straight below it: the sub-step's horizontal direction, else +x), to exactly distance c (horizontal
distance sqrt(c² − dz²), dz the end-effector's height above the ball's centre). It then stays where it was left.
Only a hand moving *into* the ball pushes: one at rest or moving away leaves it (the first frame never changes,
and a ball just released under the open gripper is not shoved sideways). Closed fingers that hold nothing pass through the ball as without pushing (the
grab rule is unchanged), so pushing changes nothing for a gripper that never opens near the ball.

Missed picks (``pick_miss`` > 0, :func:`miss_start`): a pick-and-place
motion whose ball lies away from the grasp, so the gripper closes beside it,
lifts and places nothing while the ball stays where it lay. Whether an
episode misses and where its ball lies come from a second generator, so
``pick_miss = 0`` draws nothing from it and leaves every episode as it was.

Open picks (``pick_open`` > 0): a pick-and-place motion whose gripper never
closes; the arm reaches the ball, lifts, carries and places with open fingers,
and the ball stays where it lay (the carry rule attaches it only on closing).
Drawn from the same second generator after the miss (a missed pick is never
also open), only when ``pick_open`` > 0, so a set made without it is unchanged.

Mistimed picks (``pick_timing`` > 0): a pick-and-place motion that neither misses nor stays open, whose gripper
closes at the wrong time: **early**, :func:`decision_margin` frames before the end-effector first comes within
the grab distance of the ball (it passes over the ball with closed fingers), or **late**, as many frames after it
has left it (it stays open through the grasp); either way the arm motion is the same and the ball stays where it
lay. Which episodes, and which side (half each), come from the same second generator after the open draw, only
when ``pick_timing`` > 0; a side the plan has no room for gives way to the other, and a plan with room for neither
keeps its on-time close (``Motion.mistimed`` is then None). The counterfactual benchmark's ``close_early`` and
``close_late`` variants (:mod:`oscar_core.toyworld.counterfactual`) are made by the same rule, so data made with
it shows the model the decision the benchmark asks about.

Pushing (``push=True`` in :func:`sample_motion`, off by default): the ball moves under the push rule as well
(:data:`PUSH_CONTACT_RADII` ball radii), so an open gripper that comes down on it or sweeps through it shoves it;
it draws nothing, so the same generator gives the same arm motion either way.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import OscarError
from ..kinematics.trajectory import Trajectory
from ..kinematics.workspace import (
    ee_points,
    joint_limits,
    open_fk,
    openness_to_signal,
    reach_of,
)
from ..plugin.embodiment import Embodiment

__all__ = [
    "ToyWorldError",
    "check_supported",
    "is_hand",
    "joint_limits",
    "Motion",
    "sample_motion",
    "carry_object",
    "min_jerk",
    "openness_to_signal",
    "ee_points",
    "miss_start",
    "decision_margin",
    "grab_window",
    "mistimed_openness",
    "GRAB_RADII",
    "PUSH_CONTACT_RADII",
    "MISS_NEAR_RADII",
    "MISS_FAR_RADII",
    "MISS_NEAR_FRACTION",
]

OPEN_THRESHOLD = 0.5
#: The carry rule's grab distance, ball radii.
GRAB_RADII = 2.2
#: The push rule's contact distance, ball radii: the ball's radius plus the end-effector marker's (0.6 ball radii,
#: the magenta sphere :func:`~oscar_core.toyworld.episode.render_world` draws), so a push starts when they touch.
PUSH_CONTACT_RADII = 1.6
#: A missed pick's ball: horizontal distance from the grasp end-effector, ball radii, in the near band (just
#: outside the grab distance: it teaches the threshold) with probability MISS_NEAR_FRACTION, else the far band.
#: The end-effector grasps 1.4-2.6 radii above the floor, so every miss is more than GRAB_RADII away in 3-D.
MISS_NEAR_RADII = (2.3, 3.0)
MISS_FAR_RADII = (3.0, 6.0)
MISS_NEAR_FRACTION = 0.5


class ToyWorldError(OscarError, ValueError):
    """An embodiment or an input the toy world cannot use; the message says which and why."""


def is_hand(emb: Embodiment) -> bool:
    """True for a keypoint embodiment with the ``mano`` plugin's two-hand, 21-point skeleton (the toy world's
    hands: :mod:`oscar_core.toyworld.hand`)."""
    from oscar_embodiments.mano.topology import POINT_NAMES

    return (not emb.uses_kinematic_tree()) and tuple(emb.skeleton.links) == POINT_NAMES


def check_supported(emb: Embodiment, hands: bool = False) -> None:
    """Raise :class:`ToyWorldError` unless ``emb`` computes its skeleton from a kinematic tree (URDF/xacro), or,
    with ``hands``, is a hand with the ``mano`` plugin's skeleton (:func:`is_hand`)."""
    if not emb.uses_kinematic_tree():
        if hands and is_hand(emb):
            return
        raise ToyWorldError(
            f"toyworld: embodiment {emb.name!r} reads its skeleton from keypoints (it overrides Embodiment.frames); "
            f"the toy world draws joint-space motions inside URDF limits for kinematic-tree embodiments (urdf/xacro)"
            + (" and hands with the mano plugin's 2 x 21-point skeleton" if hands else "")
        )
    if len(emb.joint_names) == 0:
        raise ToyWorldError(f"toyworld: embodiment {emb.name!r} has no movable joints to move")
    if len(emb.edges) == 0:
        raise ToyWorldError(f"toyworld: embodiment {emb.name!r} has no skeleton edges to draw")


def min_jerk(keys: np.ndarray, times: np.ndarray, T: int) -> np.ndarray:
    """Piecewise minimum-jerk interpolation: keys (N, J) at integer frames ``times`` (N,), increasing,
    times[0] = 0, times[-1] = T - 1 → (T, J). Each segment is a convex blend of its two keys."""
    keys = np.asarray(keys, dtype=np.float64)
    out = np.empty((T, keys.shape[1]))
    for k in range(len(times) - 1):
        t0, t1 = int(times[k]), int(times[k + 1])
        s = (np.arange(t0, t1 + 1) - t0) / max(t1 - t0, 1)
        w = 10 * s**3 - 15 * s**4 + 6 * s**5
        out[t0 : t1 + 1] = keys[k] + w[:, None] * (keys[k + 1] - keys[k])
    return out


def carry_object(
    ee: np.ndarray,
    openness: np.ndarray,
    start: np.ndarray,
    radius: float,
    grab_distance: float,
    *,
    push_contact: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Object positions under the attachment rule of the module docstring.

    ee: (T, 3) end-effector, metres; openness: (T,) of the gripper that
    grabs, in [0, 1]; start: (3,) the ball's centre at frame 0 (z = radius).
    push_contact: None (default) for no pushing (the ball moves only when grabbed), else the push rule's
    contact distance in metres (> 0; the toy world's is :data:`PUSH_CONTACT_RADII` x ``radius``).
    Returns positions (T, 3) metres and attached (T,) bool.
    """
    if push_contact is not None:
        _check_push_contact(push_contact)
        return _carry_and_push(ee, openness, start, radius, grab_distance, float(push_contact))
    T = len(ee)
    pos = np.empty((T, 3))
    attached = np.zeros(T, dtype=bool)
    p = np.asarray(start, dtype=np.float64).copy()
    offset = None
    for t in range(T):
        closed = openness[t] < OPEN_THRESHOLD
        was_open = t == 0 or openness[t - 1] >= OPEN_THRESHOLD
        if offset is not None and not closed:  # release: drop to the floor below
            offset = None
            p = np.array([p[0], p[1], radius])
        if offset is None and closed and was_open and np.linalg.norm(ee[t] - p) <= grab_distance:
            offset = p - ee[t]
        if offset is not None:
            p = ee[t] + offset
            attached[t] = True
        pos[t] = p
    return pos, attached


def _check_push_contact(push_contact) -> None:
    if isinstance(push_contact, bool) or not isinstance(push_contact, (int, float, np.floating)):
        raise ToyWorldError(
            f"toyworld carry rule: push_contact: expected a contact distance in metres > 0 or None (no pushing), "
            f"found {push_contact!r}"
        )
    if not (np.isfinite(push_contact) and push_contact > 0):
        raise ToyWorldError(
            f"toyworld carry rule: push_contact: expected a finite contact distance in metres > 0, found {push_contact}"
        )


def _push_out(p: np.ndarray, c: np.ndarray, was: np.ndarray, contact: float, step_xy: np.ndarray) -> np.ndarray:
    """The ball's centre ``p`` (3,) after the end-effector moves from ``was`` to ``c`` (3,): unchanged unless it
    came closer and is closer than ``contact`` (metres), else slid along the floor to exactly ``contact`` from ``c``
    (module docstring). step_xy: (2,) the sub-step's horizontal motion, the direction used when ``c`` is straight
    above the ball."""
    dz = float(c[2] - p[2])
    near = float(np.linalg.norm(p - c))
    if abs(dz) >= contact or near >= contact or near >= np.linalg.norm(p - was):
        return p
    reach = float(np.sqrt(contact * contact - dz * dz))
    d = p[:2] - c[:2]
    dist = float(np.linalg.norm(d))
    if dist > 1e-12:
        u = d / dist
    elif np.linalg.norm(step_xy) > 1e-12:
        u = step_xy / np.linalg.norm(step_xy)
    else:
        u = np.array([1.0, 0.0])
    return np.array([c[0] + reach * u[0], c[1] + reach * u[1], p[2]])


def _carry_and_push(ee, openness, start, radius: float, grab_distance: float, contact: float):
    """:func:`carry_object` with the push rule (module docstring); same release and grab steps."""
    ee = np.asarray(ee, dtype=np.float64)
    T = len(ee)
    pos = np.empty((T, 3))
    attached = np.zeros(T, dtype=bool)
    p = np.asarray(start, dtype=np.float64).copy()
    offset = None
    for t in range(T):
        closed = openness[t] < OPEN_THRESHOLD
        was_open = t == 0 or openness[t - 1] >= OPEN_THRESHOLD
        if offset is not None and not closed:  # release: drop to the floor below
            offset = None
            p = np.array([p[0], p[1], radius])
        if offset is None and not closed:  # an open gripper holding nothing pushes
            prev = ee[max(t - 1, 0)]
            step = ee[t] - prev
            n = max(1, int(np.ceil(np.linalg.norm(step) / (0.25 * contact))))
            was = prev
            for c in prev + step * (np.arange(1, n + 1) / n)[:, None]:
                p = _push_out(p, c, was, contact, step[:2])
                was = c
        if offset is None and closed and was_open and np.linalg.norm(ee[t] - p) <= grab_distance:
            offset = p - ee[t]
        if offset is not None:
            p = ee[t] + offset
            attached[t] = True
        pos[t] = p
    return pos, attached


@dataclass(frozen=True)
class Motion:
    """One episode's motion.

    trajectory: the robot's :class:`Trajectory` (T frames, raw gripper
    signals); kind: "pick_place" or "reach"; points: (T, K, 3) skeleton
    points, metres; ee: (T, 3) end-effector, metres; object: (T, 3) ball
    centre, metres; attached: (T,) bool; object_radius: metres; scale:
    the robot's reach, metres (sizes of everything else follow it);
    link_radii: (E,) capsule radii, metres (None: :func:`~oscar_core.render.capsules.link_radii` of the
    reach); marker: draw the end-effector marker (robots with a gripper; hands have none).
    """

    trajectory: Trajectory
    kind: str
    points: np.ndarray
    ee: np.ndarray
    object: np.ndarray
    attached: np.ndarray
    object_radius: float
    scale: float
    missed: bool = False  # a pick_place motion whose ball lay out of the gripper's reach (module docstring)
    never_closed: bool = False  # a pick_place motion whose gripper stayed open (an open pick, module docstring)
    # "early" / "late": a pick_place motion whose gripper closed off the ball (module docstring, "Mistimed picks")
    mistimed: str | None = None
    link_radii: np.ndarray | None = None
    marker: bool = True


def decision_margin(frames: int) -> int:
    """Frames between a mistimed close and the grab-distance boundary (close early / late), and the half-width of a
    counterfactual miss's full shift: 5 % of a ``frames``-frame episode, at least 2."""
    return max(2, int(round(0.05 * (frames - 1))))


def grab_window(ee: np.ndarray, ball: np.ndarray, radius: float, close_at: int) -> tuple[np.ndarray, int, int | None]:
    """Where the end-effector is within the carry rule's grab distance of the ball, around a close on ``close_at``.

    ee: (T, 3) metres; ball: (3,) metres, its centre; radius: metres. Returns ``(inside, enter, leave)``: (T,) bool,
    the first frame inside (0 when none is), and the first frame outside after ``close_at`` (None when it never
    leaves)."""
    inside = np.linalg.norm(np.asarray(ee) - np.asarray(ball), axis=1) <= GRAB_RADII * radius
    left = np.flatnonzero(~inside[close_at:])
    return inside, int(np.argmax(inside)), close_at + int(left[0]) if len(left) else None


def mistimed_openness(
    openness: np.ndarray, ee: np.ndarray, ball: np.ndarray, radius: float, side: str
) -> np.ndarray | None:
    """The first gripper's openness with its close moved off the ball (module docstring, "Mistimed picks"), or
    None when the plan has no room for ``side`` ("early" or "late").

    openness: (T, G) in [0, 1], the on-time plan (closed from its close frame to its release); ee: (T, 3) metres,
    the end-effector's path; ball: (3,) metres, the ball's centre; radius: metres. Early: closed from
    :func:`decision_margin` frames before the end-effector first comes within the grab distance, through the
    release. Late: open until as many frames after it leaves the grab distance, closed from then to the release.
    The frame before a close is 0.6 open (fingers on the way), as in the plan."""
    o = np.asarray(openness, dtype=np.float64)
    T = len(o)
    closed = np.flatnonzero(o[:, 0] < OPEN_THRESHOLD)
    if not len(closed):
        return None
    close_at = int(closed[0])
    reopen = np.flatnonzero(o[close_at:, 0] >= OPEN_THRESHOLD)
    release = close_at + int(reopen[0]) if len(reopen) else T
    inside, enter, leave = grab_window(ee, ball, radius, close_at)
    if not inside[close_at]:
        return None
    m = decision_margin(T)
    out = o.copy()
    if side == "early":
        at = enter - m  # every frame before the first inside one is outside
        if at < 2:
            return None
        out[at:release, 0] = 0.0
    elif side == "late":
        if leave is None:
            return None
        at = leave + m
        if at >= release - 1 or inside[at:release].any():  # a close back inside the grab distance would grab
            return None
        out[:at, 0] = 1.0
        out[at:release, 0] = 0.0
    else:
        raise ValueError(f"mistimed_openness: side: expected 'early' or 'late', found {side!r}")
    out[at - 1, 0] = 0.6
    return out


def miss_start(
    rng: np.random.Generator, grasp_xy: np.ndarray, base_xy: np.ndarray, radius: float, scale: float
) -> np.ndarray:
    """(2,) floor position, metres, of a missed pick's ball: at a distance from ``grasp_xy`` (the grasp
    end-effector, metres) drawn from the near band with probability :data:`MISS_NEAR_FRACTION` (else the far
    band), in ``radius`` units, at the first of 16 uniform angles that keeps it at least 0.25 ``scale`` from the
    robot's base ``base_xy`` (as every reaching episode's ball is; the farthest of them if none does).
    Always makes the same draws (1 + 1 + 16 uniforms)."""
    near = rng.uniform() < MISS_NEAR_FRACTION
    lo, hi = MISS_NEAR_RADII if near else MISS_FAR_RADII
    d = rng.uniform(lo, hi) * radius
    ang = rng.uniform(-np.pi, np.pi, 16)
    cand = np.asarray(grasp_xy, dtype=np.float64)[:2] + d * np.stack([np.cos(ang), np.sin(ang)], 1)
    from_base = np.linalg.norm(cand - np.asarray(base_xy, dtype=np.float64)[:2], axis=1)
    ok = np.flatnonzero(from_base >= 0.25 * scale)
    return cand[ok[0] if len(ok) else int(np.argmax(from_base))]


@dataclass
class _CandidatePoses:
    """Random joint poses of one embodiment and what the motion picks from them.

    q: (N, J) radians; ee: (N, 3) end-effector positions in metres; base: (3,) the base's position; scale: the
    arm's reach in metres; radius: the ball's radius in metres; valid: indices of poses above the floor (and
    away from the base when any are); grasp: valid poses with the end effector at the ball's height; high:
    valid poses well above it.
    """

    q: np.ndarray
    ee: np.ndarray
    base: np.ndarray
    scale: float
    radius: float
    valid: np.ndarray
    grasp: np.ndarray
    high: np.ndarray


def _candidate_poses(emb: Embodiment, rng: np.random.Generator, n_candidates: int) -> _CandidatePoses:
    """``n_candidates`` poses drawn uniformly within the joint limits from ``rng``, sorted into the sets a motion
    picks its key poses from."""
    lo, hi = joint_limits(emb)
    J = len(lo)
    q = lo + rng.uniform(0, 1, (n_candidates, J)) * (hi - lo)
    pts, ee = open_fk(emb, q)
    base = pts[:, 0].mean(0)
    scale = reach_of(pts, ee)
    R = 0.09 * scale  # a ball about 7 pixels across at 64 x 64
    above = (pts[..., 2].min(1) >= -0.02 * scale) & (ee[:, 2] >= R)
    far = np.linalg.norm(ee[:, :2] - base[:2], axis=1) >= 0.25 * scale
    valid = np.flatnonzero(above & far)
    if len(valid) == 0:
        valid = np.flatnonzero(above)
    if len(valid) == 0:
        valid = np.argsort(-pts[..., 2].min(1))[:8]  # least-bad poses: the floor hides what is under it
    grasp = valid[np.abs(ee[valid, 2] - 2 * R) <= 0.6 * R]
    high = valid[ee[valid, 2] >= 2 * R + 0.25 * scale]
    return _CandidatePoses(q, ee, base, scale, R, valid, grasp, high)


def _pick_place(
    poses: _CandidatePoses, rng, T: int, G: int, pick_miss: float, miss_rng, pick_open: float, pick_timing: float
):
    """A pick-and-place through the poses, or None when no place pose lies far enough from the grasp (then the
    draws from ``rng`` made so far stand and the motion is a reach). Returns ``(q, openness, ball, missed,
    never_closed, timing)``: (T, J) radians, (T, G) openness in [0, 1], the ball's (3,) start in metres, whether the
    grasp misses the ball or the gripper stays open, and the side ("early" / "late") its close is to be moved to or
    None (all drawn as :func:`sample_motion` says; the move itself needs the end-effector's path)."""
    q, ee, grasp, high, R, scale = poses.q, poses.ee, poses.grasp, poses.high, poses.radius, poses.scale
    g = int(rng.choice(grasp))
    d = np.linalg.norm(ee[grasp, :2] - ee[g, :2], axis=1)
    far_enough = grasp[d >= 0.2 * scale]
    if not len(far_enough):
        return None
    p = int(rng.choice(far_enough))
    mid = (q[g] + q[p]) / 2
    lift = int(high[np.argmin(np.linalg.norm(q[high] - mid, axis=1))])
    start = int(rng.choice(high)) if rng.uniform() < 0.7 else int(rng.choice(poses.valid))
    end = int(rng.choice(high))
    a = int(round((T - 1) * rng.uniform(0.28, 0.38)))
    hold = a + max(1, int(round(0.1 * (T - 1))))
    b = int(round((T - 1) * rng.uniform(0.72, 0.8)))
    b = min(max(b, hold + 2), T - 2)
    release = min(b + max(1, int(round(0.08 * (T - 1)))), T - 1)
    times = np.array([0, a, hold, (hold + b) // 2, b, release, T - 1])
    keys = q[[start, g, g, lift, p, p, end]]
    times, keep = np.unique(times, return_index=True)
    keys = keys[keep]
    qt = min_jerk(keys, times, T)
    openness = np.ones((T, G))
    close_at = (a + hold) // 2 if hold > a + 1 else hold
    openness[close_at:release, 0] = 0.0
    if close_at > 0:
        openness[close_at - 1, 0] = 0.6  # one in-between frame: fingers on the way
    obj0 = np.array([ee[g, 0], ee[g, 1], R])
    missed = never_closed = False
    timing = None
    if pick_miss > 0 or pick_open > 0 or pick_timing > 0:
        mrng = miss_rng if miss_rng is not None else np.random.Generator(rng.bit_generator.jumped())
        if pick_miss > 0:
            missed = bool(mrng.uniform() < pick_miss)
            xy = miss_start(mrng, ee[g, :2], poses.base[:2], R, scale)  # drawn either way: F only picks who misses
            if missed:
                obj0 = np.array([xy[0], xy[1], R])
        if pick_open > 0 and not missed:
            never_closed = bool(mrng.uniform() < pick_open)
            if never_closed:
                openness[:, 0] = 1.0
        if pick_timing > 0:  # both drawn either way: F only picks who is mistimed
            who, early = mrng.uniform() < pick_timing, mrng.uniform() < 0.5
            if who and not (missed or never_closed):
                timing = "early" if early else "late"
    return qt, openness, obj0, missed, never_closed, timing


def _reach(poses: _CandidatePoses, rng, T: int, G: int):
    """A reach through 3 or 4 random valid poses, each gripper switching open/closed at most once, the ball
    somewhere on the floor in the workspace. Returns ``(q, openness, ball)``: (T, J) radians, (T, G) in [0, 1],
    (3,) metres."""
    n_keys = int(rng.integers(3, 5))
    keys = poses.q[rng.choice(poses.valid, size=n_keys)]
    times = np.unique(np.round(np.linspace(0, T - 1, n_keys)).astype(int))
    qt = min_jerk(keys[: len(times)], times, T)
    openness = np.ones((T, G))
    for i in range(G):
        if rng.uniform() < 0.6:
            t0 = int(rng.integers(1, T - 1))
            openness[t0:, i] = 0.0 if rng.uniform() < 0.5 else 1.0
            openness[:t0, i] = 1.0 - openness[t0, i]
    k = int(rng.choice(poses.valid))
    return qt, openness, np.array([poses.ee[k, 0], poses.ee[k, 1], poses.radius])


def sample_motion(
    emb: Embodiment,
    rng: np.random.Generator,
    frames: int,
    fps: float = 10.0,
    pick_place_prob: float = 0.75,
    n_candidates: int = 768,
    pick_miss: float = 0.0,
    miss_rng: np.random.Generator | None = None,
    pick_open: float = 0.0,
    push: bool = False,
    pick_timing: float = 0.0,
) -> Motion:
    """A smooth random motion of ``frames`` frames: pick-and-place (when the robot has a gripper, can
    reach the floor and ``frames`` >= 9) with probability ``pick_place_prob``, else reaching through random poses.

    pick_miss: probability in [0, 1] that a pick-and-place motion misses (its ball placed by
    :func:`miss_start`; the joint motion and gripper are unchanged). The miss is drawn from ``miss_rng``
    (default: a copy of ``rng``'s bit generator jumped far ahead, which leaves ``rng``'s stream as it was),
    never from ``rng``, and only when ``pick_miss`` > 0: the same ``rng`` gives the same robot motion for
    every ``pick_miss``, and with the same ``miss_rng`` an episode that misses at F misses at every F' > F.
    pick_open: probability in [0, 1] that a pick-and-place motion that did not miss keeps its gripper open
    throughout (the joint motion unchanged; the ball stays), drawn from ``miss_rng`` after the miss.
    push: the ball also moves under the push rule (module docstring); draws nothing.
    pick_timing: probability in [0, 1] that a pick-and-place motion that neither missed nor stayed open closes its
    gripper early or late (module docstring, "Mistimed picks"), drawn from ``miss_rng`` after the open draw.
    """
    check_supported(emb)
    if frames < 5:
        raise ToyWorldError(f"toyworld: --frames: expected at least 5 frames, found {frames}")
    if not (isinstance(pick_miss, (int, float)) and 0.0 <= pick_miss <= 1.0):
        raise ToyWorldError(f"toyworld: --pick-miss: expected a fraction in [0, 1], found {pick_miss!r}")
    if not (isinstance(pick_open, (int, float)) and 0.0 <= pick_open <= 1.0):
        raise ToyWorldError(f"toyworld: --pick-open: expected a fraction in [0, 1], found {pick_open!r}")
    if not (isinstance(pick_timing, (int, float)) and 0.0 <= pick_timing <= 1.0):
        raise ToyWorldError(f"toyworld: --pick-timing: expected a fraction in [0, 1], found {pick_timing!r}")
    if not isinstance(push, bool):
        raise ToyWorldError(f"toyworld: --push: expected True or False, found {push!r}")
    poses = _candidate_poses(emb, rng, n_candidates)
    G = len(emb.grippers)
    T = frames
    kind = "reach"
    missed = never_closed = False
    picked = timing = mistimed = None
    if G and T >= 9 and len(poses.grasp) >= 2 and len(poses.high) >= 1 and rng.uniform() < pick_place_prob:
        picked = _pick_place(poses, rng, T, G, pick_miss, miss_rng, pick_open, pick_timing)
    if picked is not None:
        kind = "pick_place"
        qt, openness, obj0, missed, never_closed, timing = picked
    else:
        qt, openness, obj0 = _reach(poses, rng, T, G)
    R, scale = poses.radius, poses.scale

    def trajectory(o):
        signal = openness_to_signal(emb, o)
        return Trajectory(emb.joint_names, qt, fps, signal, emb.gripper_names or None, source=f"<toyworld {emb.name}>")

    traj = trajectory(openness)
    points, ee_t = ee_points(emb, traj)
    if timing is not None:  # the close moves off the ball: the side drawn, else the other, else none
        for side in (timing, "late" if timing == "early" else "early"):
            moved = mistimed_openness(openness, ee_t, obj0, R, side)
            if moved is not None:
                openness, mistimed = moved, side
                traj = trajectory(openness)
                points, ee_t = ee_points(emb, traj)
                break
    if G:
        contact = PUSH_CONTACT_RADII * R if push else None
        obj, attached = carry_object(ee_t, openness[:, 0], obj0, R, grab_distance=GRAB_RADII * R, push_contact=contact)
    else:
        obj, attached = np.repeat(obj0[None], T, 0), np.zeros(T, dtype=bool)
    return Motion(
        traj, kind, points, ee_t, obj, attached, R, scale, missed, never_closed=never_closed, mistimed=mistimed
    )
