"""Scripted pick-and-place policies in the toy world, and the ``oscar eval run`` manifest of their episodes.

A **session** is one scene: embodiment, camera, scene look, the ball's start
position, the place position and the robot's start and end poses, all fixed,
so every policy of a session starts from the same first frame. A **policy**
is the scripted pick-and-place of :mod:`~oscar_core.toyworld.motion`
(start → grasp, the gripper closes → lift → place, the gripper opens → end;
joint-space keyframes joined by minimum-jerk segments, poses found by
forward kinematics of sampled configurations, no IK) whose grasp is aimed at
the ball's centre plus an error drawn per episode from a 2D Gaussian of
standard deviation ``aim_sigma`` ball radii (:data:`POLICIES`). The grasp pose
is the sampled configuration whose end-effector is nearest the aimed point
(2 ball radii above the floor), refined by a few rounds of random
perturbations in joint space (still only sampling + FK).

**Real success** is the toy simulator's outcome under the attachment rule of
:func:`~oscar_core.toyworld.motion.carry_object` (grab distance 2.2 ball
radii): the ball was grabbed and its centre ends at least
:data:`SUCCESS_RADII` ball radii (horizontally) from where it started. The
place pose puts the end-effector at least :data:`PLACE_MIN_RADII` radii from
the ball, so a grabbed ball always travels well past the threshold.

:func:`~oscar_core.toyworld.policy_eval_write.write_policy_eval` writes one folder per session (first frame PNG,
camera JSON, one trajectory ``.npz`` and one rendered real episode ``.mkv``
per policy) and ``manifest.json`` in the ``oscar eval run`` format
(docs/evaluation.md); each cell's ``info`` carries what
:func:`oscar_core.toyworld.judge.ball_moved` needs: the ball's start pixel,
its radius in pixels and the homography from pixels to the plane of the
resting ball's centre in ball radii.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field

import numpy as np

from .._util.log import get_logger
from ..camera import Camera, project
from ..kinematics.trajectory import Trajectory
from ..kinematics.workspace import ee_points, joint_limits, open_fk, openness_to_signal, reach_of
from ..plugin.embodiment import Embodiment
from .motion import GRAB_RADII, Motion, ToyWorldError, carry_object, check_supported, min_jerk

__all__ = [
    "Policy",
    "POLICIES",
    "SUCCESS_RADII",
    "PLACE_MIN_RADII",
    "GRAB_RADII",
    "Session",
    "PolicyEpisode",
    "plan_session",
    "policy_eval_refusal",
    "CANDIDATE_ROUNDS",
    "policy_motion",
    "session_rng",
    "floor_homography",
    "TASK",
]

_log = get_logger(__name__)

#: The ball must end at least this many ball radii (horizontally) from its start for a success.
SUCCESS_RADII = 3.0
#: The place pose's end-effector is at least this many ball radii from the ball's start.
PLACE_MIN_RADII = 6.0
TASK = "pick up the yellow ball and put it down elsewhere"


@dataclass(frozen=True)
class Policy:
    """A scripted pick-and-place: the grasp is aimed at the ball plus an error ~ N(0, aim_sigma²) per axis,
    in ball radii (horizontal plane)."""

    name: str
    aim_sigma: float


#: The default policies, best first.
POLICIES: tuple[Policy, ...] = (
    Policy("expert", 0.3),
    Policy("good", 1.25),
    Policy("sloppy", 2.0),
    Policy("random", 4.0),
)


@dataclass
class PolicyEpisode:
    """One policy's episode in a session: its motion, real outcome and aim.

    aim_error: (2,) the drawn aiming error, ball radii; grasp_error: (2,) where the
    grasp pose's end-effector actually is relative to the ball, ball radii;
    displacement: horizontal distance the ball moved by the end, ball radii.
    """

    policy: Policy
    motion: Motion
    success: int
    grabbed: bool
    displacement: float
    aim_error: np.ndarray
    grasp_error: np.ndarray


@dataclass
class Session:
    """One scene shared by every policy: start pose, ball, place pose, timing, scene and camera.

    ball: (3,) the ball's start centre, metres (z = radius); radius, scale: metres;
    episodes: one :class:`PolicyEpisode` per policy, in policy order.
    """

    embodiment: str
    ball: np.ndarray
    radius: float
    scale: float
    scene: object
    camera: Camera
    episodes: list[PolicyEpisode] = field(default_factory=list)


def session_rng(
    seed: int, embodiment: str, index: int, attempt: int = 0, policy: str | None = None
) -> np.random.Generator:
    """The generator of session ``index`` of ``embodiment`` (and of one policy's aim in it): independent of
    every other session, and of the training episodes of the same seed (``episode_rng``)."""
    words = [int(seed), zlib.crc32(embodiment.encode()), int(index), 0x9E55, int(attempt)]
    if policy is not None:
        words.append(zlib.crc32(policy.encode()))
    return np.random.default_rng(np.random.SeedSequence(words))


def _reach(
    emb: Embodiment,
    q: np.ndarray,
    ee: np.ndarray,
    ok: np.ndarray,
    target: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    floor: float,
    rng: np.random.Generator,
    rounds: int = 10,
    keep: int = 6,
    proposals: int = 24,
) -> np.ndarray:
    """The configuration (J,) whose end-effector is nearest ``target`` (3,) metres: the best of the candidates
    ``q`` (N, J) (``ee`` (N, 3), ``ok`` (N,) allowed), refined by ``rounds`` of Gaussian perturbations in joint
    space with a shrinking step; a proposal with a skeleton point below ``floor`` metres is rejected."""
    d = np.where(ok, np.linalg.norm(ee - target, axis=1), np.inf)
    order = np.argsort(d)[:keep]
    cur, cost = q[order].copy(), d[order].copy()
    step = 0.08 * (hi - lo)
    J = q.shape[1]
    for _ in range(rounds):
        prop = cur[:, None, :] + rng.normal(0.0, 1.0, (len(cur), proposals, J)) * step
        prop = np.clip(prop, lo, hi).reshape(-1, J)
        pts, pe = open_fk(emb, prop)
        c = np.linalg.norm(pe - target, axis=1)
        c = np.where(pts[..., 2].min(1) >= floor, c, np.inf).reshape(len(cur), proposals)
        best = c.argmin(1)
        better = c[np.arange(len(cur)), best] < cost
        cur[better] = prop.reshape(len(cur), proposals, J)[np.arange(len(cur)), best][better]
        cost[better] = c[np.arange(len(cur)), best][better]
        step = step * 0.6
    return cur[int(np.argmin(cost))]


#: Candidate configurations are drawn in rounds of ``n_candidates`` until a pick and a place exist, at most this many.
CANDIDATE_ROUNDS = 8


@dataclass
class _Candidates:
    """Sampled configurations and which of them can pick, place and lift (see :func:`_candidates`).

    q: (N, J) radians; pts: (N, K, 3), ee: (N, 3) metres; lo, hi: (J,) joint limits; scale: reach, metres;
    radius: the ball's, metres; floor: the lowest a skeleton point may go, metres; above, grasp, high, usable:
    boolean mask (N,) / indices of the floor poses, the high poses and the floor poses with a place far enough.
    """

    q: np.ndarray
    pts: np.ndarray
    ee: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    scale: float
    radius: float
    floor: float
    above: np.ndarray
    grasp: np.ndarray
    high: np.ndarray
    usable: np.ndarray


def _candidates(
    emb: Embodiment, rng: np.random.Generator, n_candidates: int, rounds: int = CANDIDATE_ROUNDS
) -> _Candidates:
    """Draw ``n_candidates`` configurations uniformly inside the joint limits (forward kinematics only), and
    another ``n_candidates`` while no floor pose has a place :data:`PLACE_MIN_RADII` ball radii away or no high
    pose exists, at most ``rounds`` times. A floor pose puts the end-effector 2 ± 0.6 ball radii above the floor
    and at least a quarter of the reach from the base; a high pose lifts it a quarter of the reach above that.
    A plan whose first round suffices draws exactly what it drew before rounds existed."""
    lo, hi = joint_limits(emb)
    J = len(lo)
    qs, ps, es = [], [], []
    for _ in range(max(1, rounds)):
        q1 = lo + rng.uniform(0, 1, (n_candidates, J)) * (hi - lo)
        p1, e1 = open_fk(emb, q1)
        qs.append(q1), ps.append(p1), es.append(e1)
        q, pts, ee = (np.concatenate(a) for a in (qs, ps, es))
        base = pts[:, 0].mean(0)
        scale = reach_of(pts, ee)
        R = 0.09 * scale  # as sample_motion: a ball about 7 pixels across at 64 x 64
        floor = -0.02 * scale
        above = (pts[..., 2].min(1) >= floor) & (ee[:, 2] >= R)
        grasp = np.flatnonzero(
            above
            & (np.abs(ee[:, 2] - 2 * R) <= 0.6 * R)
            & (np.linalg.norm(ee[:, :2] - base[:2], axis=1) >= 0.25 * scale)
        )
        high = np.flatnonzero(above & (ee[:, 2] >= 2 * R + 0.25 * scale))
        far = np.linalg.norm(ee[grasp, None, :2] - ee[None, grasp, :2], axis=-1) >= PLACE_MIN_RADII * R
        usable = grasp[far.any(1)]
        if len(usable) and len(high):
            break
    return _Candidates(q, pts, ee, lo, hi, scale, R, floor, above, grasp, high, usable)


def policy_eval_refusal(emb: Embodiment, n_candidates: int = 768) -> str | None:
    """Why ``emb`` cannot do the toy world's pick-and-place, or None when it can: checked before anything is
    written, on :data:`CANDIDATE_ROUNDS` x ``n_candidates`` configurations of a fixed generator (what one session
    may draw). The reasons: not a kinematic-tree embodiment, no gripper, no floor pose, no lifted pose, or floor
    poses that never lie :data:`PLACE_MIN_RADII` ball radii apart (the arm reaches too small a patch of floor
    around its base, which the toy world never moves)."""
    try:
        check_supported(emb)
    except ToyWorldError as exc:
        return str(exc).removeprefix("toyworld: ")
    if not len(emb.grippers):
        return f"embodiment {emb.name!r} has no gripper to pick with"
    rounds = CANDIDATE_ROUNDS
    c = _candidates(emb, np.random.default_rng(0), n_candidates * rounds, rounds=1)
    if len(c.grasp) < 2 or len(c.high) < 1:
        return (
            f"embodiment {emb.name!r}: expected poses that reach the floor and lift well above it, found "
            f"{len(c.grasp)} floor and {len(c.high)} high poses in {len(c.q)} sampled configurations"
        )
    if len(c.usable) == 0:
        xy = c.ee[c.grasp, :2]
        span = float(np.linalg.norm(xy[:, None] - xy[None], axis=-1).max())
        return (
            f"embodiment {emb.name!r}: its end-effector reaches the floor over a patch {span:.2f} m across "
            f"(its base stays still in the toy world), and a pick-and-place needs a place "
            f"{PLACE_MIN_RADII:g} ball radii = {PLACE_MIN_RADII * c.radius:.2f} m from the ball "
            f"({len(c.q)} sampled configurations)"
        )
    return None


def plan_session(
    emb: Embodiment,
    rng: np.random.Generator,
    width: int,
    height: int,
    frames: int,
    fps: float = 10.0,
    policies=POLICIES,
    policy_rngs: dict | None = None,
    n_candidates: int = 768,
    rounds: int = CANDIDATE_ROUNDS,
) -> Session:
    """Plan one session and every policy's episode in it (no rendering).

    rng: the session's generator (scene, ball, poses, timing, camera);
    policy_rngs: ``{policy name: generator}`` for the aiming errors (default:
    drawn from ``rng``); n_candidates, rounds: configurations sampled per round,
    at most that many rounds (:func:`_candidates`). Raises :class:`ToyWorldError` when the robot cannot
    do the task (no gripper, fewer than 9 frames, no reachable place far
    enough from the ball), ``ValueError`` when no camera sees it all.
    """
    from .scene import sample_camera, sample_scene

    check_supported(emb)
    if not len(emb.grippers):
        raise ToyWorldError(f"toyworld policy-eval: embodiment {emb.name!r} has no gripper to pick with")
    if frames < 9:
        raise ToyWorldError(f"toyworld policy-eval: --frames: expected at least 9 frames, found {frames}")
    c = _candidates(emb, rng, n_candidates, rounds)
    q, pts, ee, above, grasp, high, usable = c.q, c.pts, c.ee, c.above, c.grasp, c.high, c.usable
    lo, hi, scale, R, floor = c.lo, c.hi, c.scale, c.radius, c.floor
    if len(grasp) < 2 or len(high) < 1:
        raise ToyWorldError(
            f"toyworld policy-eval: embodiment {emb.name!r}: expected poses that reach the floor and "
            f"lift well above it, found {len(grasp)} floor and {len(high)} high poses"
        )
    if len(usable) == 0:
        raise ToyWorldError(
            f"toyworld policy-eval: embodiment {emb.name!r}: expected two floor poses at least "
            f"{PLACE_MIN_RADII} ball radii apart, found none in {len(q)} sampled configurations"
        )
    g = int(rng.choice(usable))
    ball = np.array([ee[g, 0], ee[g, 1], R])
    places = grasp[np.linalg.norm(ee[grasp, :2] - ball[:2], axis=1) >= PLACE_MIN_RADII * R]
    place = q[int(rng.choice(places))]
    start, end = q[int(rng.choice(high))], q[int(rng.choice(high))]
    T = frames
    a = int(round((T - 1) * rng.uniform(0.28, 0.38)))
    hold = a + max(1, int(round(0.1 * (T - 1))))
    b = int(round((T - 1) * rng.uniform(0.72, 0.8)))
    b = min(max(b, hold + 2), T - 2)
    release = min(b + max(1, int(round(0.08 * (T - 1)))), T - 1)
    times = np.array([0, a, hold, (hold + b) // 2, b, release, T - 1])
    close_at = (a + hold) // 2 if hold > a + 1 else hold
    episodes = []
    for pol in policies:
        prng = (policy_rngs or {}).get(pol.name, rng)
        aim = prng.normal(0.0, pol.aim_sigma, 2)
        target = np.array([ball[0] + aim[0] * R, ball[1] + aim[1] * R, 2 * R])
        qg = _reach(emb, q, ee, above, target, lo, hi, floor, prng)
        mid = (qg + place) / 2
        lift = q[int(high[np.argmin(np.linalg.norm(q[high] - mid, axis=1))])]
        motion = policy_motion(
            emb, [start, qg, qg, lift, place, place, end], times, close_at, release, ball, R, scale, fps
        )
        disp = float(np.linalg.norm(motion.object[-1, :2] - ball[:2]) / R)
        grabbed = bool(motion.attached.any())
        grasp_err = (motion.ee[a, :2] - ball[:2]) / R
        episodes.append(
            PolicyEpisode(pol, motion, int(grabbed and disp >= SUCCESS_RADII), grabbed, disp, aim, grasp_err)
        )
    scene = sample_scene(rng, len(emb.edges), scale)
    seen = np.concatenate(
        [
            np.concatenate(
                [ep.motion.points.reshape(-1, 3), ep.motion.object + [0, 0, R], ep.motion.object - [0, 0, R]]
            )
            for ep in episodes
        ]
    )
    camera = sample_camera(rng, seen, width, height, base_xy=pts[0, 0, :2], embodiment=emb.name)
    return Session(emb.name, ball, R, scale, scene, camera, episodes)


def policy_motion(
    emb: Embodiment,
    keys,
    times: np.ndarray,
    close_at: int,
    release: int,
    ball: np.ndarray,
    radius: float,
    scale: float,
    fps: float = 10.0,
) -> Motion:
    """A pick-and-place :class:`Motion` through joint keyframes ``keys`` (7 of (J,): start, grasp, grasp, lift,
    place, place, end) at frames ``times`` (7,): the first gripper closes at frame ``close_at`` (one in-between
    frame before) and opens at ``release``; the ball (3,) metres of ``radius`` metres moves by the carry rule."""
    keys = np.asarray(keys, dtype=np.float64)
    times, keep = np.unique(np.asarray(times), return_index=True)
    T = int(times[-1]) + 1
    qt = min_jerk(keys[keep], times, T)
    G = len(emb.grippers)
    openness = np.ones((T, G))
    openness[close_at:release, 0] = 0.0
    if close_at > 0:
        openness[close_at - 1, 0] = 0.6  # as sample_motion: fingers on the way
    traj = Trajectory(
        emb.joint_names,
        qt,
        fps,
        openness_to_signal(emb, openness),
        emb.gripper_names or None,
        source=f"<toyworld policy-eval {emb.name}>",
    )
    points, ee = ee_points(emb, traj)
    obj, attached = carry_object(ee, openness[:, 0], ball, radius, grab_distance=GRAB_RADII * radius)
    return Motion(traj, "pick_place", points, ee, obj, attached, radius, scale)


def floor_homography(camera: Camera, height_m: float, unit_m: float) -> np.ndarray:
    """(3, 3) homography from output pixels (x, y, 1) to world (x, y, 1) / ``unit_m`` on the plane z = ``height_m``
    (fitted to exact projections of a grid on that plane; exact for a pinhole camera)."""
    import cv2

    K = camera.intrinsics
    T_wc = np.linalg.inv(camera.world_to_cv())
    eye = T_wc[:3, 3]
    span = max(abs(eye[2] - height_m), unit_m) * 2
    gx, gy = np.meshgrid(np.linspace(-1, 1, 5), np.linspace(-1, 1, 5))
    # a grid on the plane around where the optical axis meets it (or under the camera)
    axis = T_wc[:3, 2]
    t = (height_m - eye[2]) / axis[2] if abs(axis[2]) > 1e-6 else 0.0
    c = eye + max(t, 0.0) * axis
    world = np.stack([c[0] + span * gx.ravel(), c[1] + span * gy.ravel(), np.full(gx.size, height_m)], 1)
    pr = project(world, camera)
    good = pr.in_front & (pr.depth > 1e-6)
    if good.sum() < 4:
        raise ValueError(
            f"floor homography: expected the plane z = {height_m:.3g} m in front of the camera, "
            f"found {int(good.sum())} of 25 grid points in front ({K.width}x{K.height} camera)"
        )
    Hm, _ = cv2.findHomography(pr.uv[good].astype(np.float64), world[good, :2] / unit_m, 0)
    return Hm


def _radius_px(s: Session) -> float:
    """The ball's radius in output pixels at its start (focal length x radius / depth)."""
    pr = project(s.ball[None], s.camera)
    return float(s.camera.intrinsics.fx * s.radius / max(float(pr.depth[0]), 1e-9))


def _png_bytes(img: np.ndarray) -> bytes:
    import cv2

    ok, buf = cv2.imencode(".png", np.ascontiguousarray(img[..., ::-1]))
    if not ok:
        raise ValueError("png encoding failed")
    return buf.tobytes()
