"""MANO model files: the restricted unpickler and the smplx path, on a synthetic model.

No licensed MANO file exists here, so the tests build one with the real
shapes (778 vertices, 1538 faces, 16 joints, a 45-d pose space, a sparse
J_regressor, chumpy arrays for shapedirs/posedirs) and pickle it the way the
official files are pickled (protocol 2). The chumpy class is a stand-in
named ``chumpy.ch.Ch`` that exists in ``sys.modules`` only while pickling.
"""

import contextlib
import os
import pickle
import sys
import types

import numpy as np
import pytest
import scipy.sparse as sp

from oscar_embodiments.mano import MANOModelError, load_mano_pickle
from oscar_embodiments.mano.mano_pickle import loads_mano_pickle

V, F, J = 778, 1538, 16
PARENTS = [0, 0, 1, 2, 0, 4, 5, 0, 7, 8, 0, 10, 11, 0, 13, 14]
TIPS = [744, 320, 443, 554, 671]  # thumb, index, middle, ring, pinky
# keypoint k <- smplx joint / tip: wrist; thumb CMC MCP IP tip; index MCP PIP DIP tip; middle; ring; pinky
KEYPOINT_SOURCES = [0, 13, 14, 15, "thumb", 1, 2, 3, "index", 4, 5, 6, "middle", 10, 11, 12, "ring", 7, 8, 9, "pinky"]


@contextlib.contextmanager
def fake_chumpy():
    """A ``chumpy.ch.Ch`` importable only inside the block, pickled like the real one."""
    chumpy, ch = types.ModuleType("chumpy"), types.ModuleType("chumpy.ch")

    class Ch:
        def __init__(self, x):
            self.x = np.asarray(x, dtype=np.float64)

        def __getstate__(self):  # what chumpy's Ch pickles: its __dict__ minus weakref caches
            return {
                "x": self.x,
                "_dirty_vars": set(),
                "_itr": None,
                "_depends_on_deps": {},
                "_make_dense": False,
                "_make_sparse": False,
            }

    class Select(Ch):  # a derived expression: no stored value
        def __getstate__(self):
            return {"a": Ch(self.x), "idxs": np.arange(3), "_dirty_vars": set()}

    for cls in (Ch, Select):
        cls.__module__ = "chumpy.ch"
        cls.__qualname__ = cls.__name__
        setattr(ch, cls.__name__, cls)
    chumpy.ch = ch
    sys.modules["chumpy"], sys.modules["chumpy.ch"] = chumpy, ch
    try:
        yield ch
    finally:
        del sys.modules["chumpy"], sys.modules["chumpy.ch"]


def synthetic_model(seed=0, left=False) -> dict:
    """Arrays with the real MANO shapes; joints are averages of three vertices."""
    rng = np.random.default_rng(seed)
    v = rng.uniform([-0.05, -0.02, -0.02], [0.12, 0.05, 0.02], size=(V, 3))
    rows = np.repeat(np.arange(J), 3)
    cols = np.concatenate([rng.choice(V, 3, replace=False) for _ in range(J)])
    jreg = sp.csc_matrix((np.full(3 * J, 1 / 3), (rows, cols)), shape=(J, V))
    weights = rng.dirichlet(np.full(J, 0.3), size=V)
    components = np.linalg.qr(rng.normal(size=(45, 45)))[0].T
    if left:
        v[:, 0] *= -1
    return {
        "v_template": v,
        "f": rng.integers(0, V, size=(F, 3)).astype(np.uint32),
        "J_regressor": jreg,
        "kintree_table": np.array([[4294967295] + PARENTS[1:], list(range(J))], dtype=np.uint32),
        "weights": weights,
        "posedirs": rng.normal(scale=1e-3, size=(V, 3, 135)),
        "shapedirs": rng.normal(scale=1e-2, size=(V, 3, 10)),
        "hands_components": components,
        "hands_mean": rng.normal(scale=0.1, size=45),
        "hands_coeffs": rng.normal(size=(1554, 45)),
        "J": jreg @ v,
        "bs_style": "lbs",
        "bs_type": "lrotmin",
    }


def pickle_model(model: dict) -> bytes:
    with fake_chumpy() as ch:
        data = dict(model, shapedirs=ch.Ch(model["shapedirs"]), posedirs=ch.Ch(model["posedirs"]))
        return pickle.dumps(data, protocol=2)


@pytest.fixture(scope="module")
def model_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("mano_models")
    (d / "MANO_RIGHT.pkl").write_bytes(pickle_model(synthetic_model(0)))
    (d / "MANO_LEFT.pkl").write_bytes(pickle_model(synthetic_model(0, left=True)))
    return d


# ---- the restricted unpickler --------------------------------------------------------------


def test_loads_chumpy_and_sparse_fields_as_numpy(model_dir):
    assert "chumpy" not in sys.modules
    model = load_mano_pickle(model_dir / "MANO_RIGHT.pkl")
    assert "chumpy" not in sys.modules  # nothing was imported
    ref = synthetic_model(0)
    assert type(model["shapedirs"]) is np.ndarray and model["shapedirs"].shape == (V, 3, 10)
    assert type(model["posedirs"]) is np.ndarray and model["posedirs"].shape == (V, 3, 135)
    assert sp.issparse(model["J_regressor"]) and model["J_regressor"].shape == (J, V)
    assert model["f"].shape == (F, 3) and model["bs_style"] == "lbs"
    for k in ("shapedirs", "posedirs", "v_template", "weights", "hands_components", "kintree_table"):
        np.testing.assert_array_equal(model[k], ref[k])
    np.testing.assert_array_equal(model["J_regressor"].toarray(), ref["J_regressor"].toarray())


def test_pickle_with_os_system_is_refused(tmp_path):
    marker = tmp_path / "pwned"

    class Evil:
        def __reduce__(self):
            return (os.system, (f"touch {marker}",))

    bad = tmp_path / "MANO_RIGHT.pkl"
    bad.write_bytes(pickle.dumps({"v_template": Evil()}, protocol=2))
    with pytest.raises(MANOModelError) as err:
        load_mano_pickle(bad)
    msg = str(err.value)
    assert str(bad) in msg and ("os.system" in msg or "posix.system" in msg) and "was refused" in msg
    assert not marker.exists()


@pytest.mark.parametrize(
    "payload",
    [
        (eval, ("1 + 1",)),
        (__import__, ("os",)),
        (__import__("subprocess").Popen, (["true"],)),
    ],
)
def test_other_callables_are_refused(payload):
    class Bad:
        def __reduce__(self):
            return payload

    with pytest.raises(MANOModelError, match="pickle global"):
        loads_mano_pickle(pickle.dumps({"x": Bad()}, protocol=2), "bad.pkl")


def test_object_arrays_and_derived_chumpy_expressions_are_refused():
    with pytest.raises(MANOModelError, match="object arrays"):
        loads_mano_pickle(pickle.dumps({"x": np.array([1, "a"], dtype=object)}, protocol=2), "obj.pkl")
    with fake_chumpy() as ch:
        data = pickle.dumps(dict(synthetic_model(1), shapedirs=ch.Select(np.zeros(3))), protocol=2)
    with pytest.raises(MANOModelError, match=r"derived.pkl: field 'shapedirs'.*chumpy.ch.Select.*derived"):
        loads_mano_pickle(data, "derived.pkl")


def test_missing_fields_and_bad_shapes_are_named():
    model = synthetic_model(2)
    del model["hands_components"]
    with pytest.raises(MANOModelError, match="field 'hands_components'.*missing"):
        loads_mano_pickle(pickle.dumps(model, protocol=2), "m.pkl")
    model = synthetic_model(2)
    model["weights"] = model["weights"][:, :15]
    with pytest.raises(MANOModelError, match=r"field 'weights': expected shape \(778, 16\)"):
        loads_mano_pickle(pickle.dumps(model, protocol=2), "m.pkl")
    with pytest.raises(MANOModelError, match="no such file"):
        load_mano_pickle("/nonexistent/MANO_RIGHT.pkl")


def test_protocol_0_pickles_load_too():
    """Old text pickles build objects through copyreg._reconstructor."""
    model = synthetic_model(3)
    with fake_chumpy() as ch:
        data = pickle.dumps(dict(model, shapedirs=ch.Ch(model["shapedirs"])), protocol=0)
    np.testing.assert_array_equal(loads_mano_pickle(data)["shapedirs"], model["shapedirs"])


# ---- the smplx path ---------------------------------------------------------------------------


smplx = pytest.importorskip("smplx")


def expected_keypoints(model, R=None, transl=None):
    """Keypoints of the rest pose rotated by R (default: identity) about the wrist joint, then shifted by transl
    (independent of smplx)."""
    R = np.eye(3) if R is None else R
    transl = np.zeros(3) if transl is None else transl
    joints = model["J_regressor"] @ model["v_template"]
    pts = np.array(
        [
            joints[s]
            if isinstance(s, int)
            else model["v_template"][TIPS[["thumb", "index", "middle", "ring", "pinky"].index(s)]]
            for s in KEYPOINT_SOURCES
        ]
    )
    return (pts - joints[0]) @ R.T + joints[0] + transl


def axis_angle(v):
    v = np.asarray(v, float)
    a = np.linalg.norm(v)
    k = v / a
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * K @ K


def test_rest_pose_joint_order_and_fingertips(model_dir):
    from oscar_embodiments.mano import mano_keypoints

    T = 3
    params = {"right": {"global_orient": np.zeros((T, 3)), "hand_pose": np.zeros((T, 45)), "transl": np.zeros((T, 3))}}
    kp = mano_keypoints(params, model_dir, flat_hand_mean=True)
    assert kp.shape == (T, 2, 21, 3)
    assert np.isnan(kp[:, 0]).all()  # no left hand given
    np.testing.assert_allclose(kp[0, 1], expected_keypoints(synthetic_model(0)), atol=1e-9)


def test_global_orientation_translation_and_left_hand(model_dir, monkeypatch):
    from oscar_embodiments.mano import mano_keypoints

    aa, t = np.array([0.3, -0.5, 0.9]), np.array([0.1, -0.2, 0.4])
    hand = {
        "global_orient": np.array([aa]),
        "hand_pose": np.zeros((1, 45)),
        "transl": np.array([t]),
        "betas": np.zeros(10),
    }
    monkeypatch.setenv("OSCAR_MANO_DIR", str(model_dir))  # found through the environment variable
    kp = mano_keypoints({"left": hand, "right": hand}, flat_hand_mean=True)
    R = axis_angle(aa)
    np.testing.assert_allclose(kp[0, 1], expected_keypoints(synthetic_model(0), R, t), atol=1e-9)
    np.testing.assert_allclose(kp[0, 0], expected_keypoints(synthetic_model(0, left=True), R, t), atol=1e-9)


def test_pca_pose_matches_smplx_own_pca_layer(model_dir):
    import torch
    from smplx.utils import Struct

    from oscar_embodiments.mano import mano_keypoints

    rng = np.random.default_rng(5)
    T, n = 4, 6
    hand = {
        "global_orient": rng.normal(scale=0.5, size=(T, 3)),
        "hand_pose": rng.normal(size=(T, n)),
        "betas": rng.normal(size=(T, 10)),
        "transl": rng.normal(scale=0.1, size=(T, 3)),
    }
    ours = mano_keypoints({"right": hand}, model_dir)[:, 1]  # flat_hand_mean=False: the mean pose is added
    model = load_mano_pickle(model_dir / "MANO_RIGHT.pkl")
    layer = smplx.MANO(str(model_dir), data_struct=Struct(**model), use_pca=True, num_pca_comps=n, dtype=torch.float64)
    with torch.no_grad():
        out = layer(**{k: torch.from_numpy(v) for k, v in hand.items()})
    ref = torch.cat([out.joints, out.vertices[:, TIPS]], dim=1).numpy()
    order = [
        s if isinstance(s, int) else 16 + ["thumb", "index", "middle", "ring", "pinky"].index(s)
        for s in KEYPOINT_SOURCES
    ]
    np.testing.assert_allclose(ours, ref[:, order], atol=1e-9)
    assert not np.allclose(ours[0], ours[1])


def test_invalid_frames_are_missing_and_trajectory_renders(model_dir):
    from oscar_core import render_skeleton_video
    from oscar_embodiments.mano import Mano, egocentric_camera, trajectory_from_mano

    T = 3
    hand = {
        "global_orient": np.tile([np.pi, 0, 0], (T, 1)),
        "hand_pose": np.zeros((T, 45)),
        "transl": np.tile([0.0, 0.0, 0.3], (T, 1)),
        "valid": [True, False, True],
    }
    hand["hand_pose"][2] = np.nan  # non-finite input: missing too
    traj = trajectory_from_mano({"right": hand}, 30.0, model_dir)
    kp = traj.keypoints.reshape(T, 2, 21, 3)
    assert np.isfinite(kp[0, 1]).all() and np.isnan(kp[1:, 1]).all() and np.isnan(kp[:, 0]).all()
    video = render_skeleton_video(Mano(), traj, egocentric_camera(200.0, 200.0, 127.5, 71.5, 256, 144))
    assert video[0].max() > 0 and video[1].max() == 0


def test_model_files_must_exist(tmp_path, monkeypatch):
    from oscar_embodiments.mano import mano_keypoints

    params = {"left": {"global_orient": np.zeros((1, 3)), "hand_pose": np.zeros((1, 45))}}
    with pytest.raises(MANOModelError, match=r"MANO_LEFT.pkl: field '<file>'.*mano.is.tue.mpg.de.*no such file"):
        mano_keypoints(params, tmp_path)
    monkeypatch.delenv("OSCAR_MANO_DIR", raising=False)
    with pytest.raises(MANOModelError, match="OSCAR_MANO_DIR"):
        mano_keypoints(params)
    with pytest.raises(ValueError, match="'left' and/or 'right'"):
        mano_keypoints({"both": params["left"]}, tmp_path)
