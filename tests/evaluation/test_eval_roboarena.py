"""`oscar eval roboarena`: a RoboArena dump (built here, as its dataset card describes it) → an `eval run` study;
bad sessions rejected one by one; resampling; the real A/B board; the three commands end to end on a tiny model."""

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from _models import tiny_world_model
from _paths import TOYARM_ASSETS

from oscar_core.calibration.score import body_video, perturb_camera
from oscar_core.camera.file import load_camera, save_camera
from oscar_core.cli import main as oscar_main
from oscar_core.evaluation import ManifestError, load_manifest
from oscar_core.evaluation.roboarena import RoboArenaError, convert_roboarena, read_session
from oscar_core.media.video import write_video
from oscar_core.plugin.registry import get_embodiment
from oscar_core.trajectory import Trajectory

W, H, T = 64, 32, 6  # video size (pixels) and control steps per episode of the test dump

# (session, {letter: (policy, binary, partial)}, preference): pi0 beats pali 3 times, loses once, ties twice
GOOD = [
    ("g1", {"A": ("pi0", 1, 1.0), "B": ("pali", 0, 0.4)}, "A"),
    ("g2", {"A": ("pali", 0, 0.2), "B": ("pi0", 1, 1.0)}, "B"),
    ("g3", {"A": ("pi0", 0, 0.7), "B": ("pali", 0, 0.1)}, "A"),
    ("g4", {"A": ("pali", 1, 1.0), "B": ("pi0", 0, 0.5)}, "A"),
    ("g5", {"A": ("pi0", 1, 1.0), "B": ("pali", 1, 1.0)}, "TIE"),
    ("g6", {"A": ("pali", 0, 0.0), "B": ("pi0", 0, 0.0)}, "tie"),
]


@pytest.fixture(autouse=True)
def isolated(tmp_path, monkeypatch):
    monkeypatch.setenv("HF_ENDPOINT", "http://127.0.0.1:9")
    monkeypatch.setenv("HF_HUB_CACHE", str(tmp_path / "hf-cache"))
    monkeypatch.setenv("OSCAR_ZOO_REGISTRY", str(tmp_path / "zoo.json"))


def _camera():
    return load_camera(TOYARM_ASSETS / "example_camera.json").resized(W, H, "stretch")


def _metadata(policies: dict, preference) -> str:
    lines = ["evaluation_location: testlab", "language_instruction: put the block in the bin"]
    lines.append(f"preference: {preference if preference is not None else 'null'}")
    lines.append("policies:")
    for letter, (name, binary, partial) in policies.items():
        lines += [f"  {letter}:", f"    policy_name: {name}", f"    binary_success: {binary}"]
        lines.append(f"    partial_success: {partial}")
    return "\n".join(lines) + "\n"


def add_session(dump: Path, name: str, policies: dict, preference, offset: int = 0, camera=None) -> Path:
    """One session folder as the card lays it out: metadata.yaml and <letter>_<policy>/ with the three videos and
    proprio_and_actions.npz; the videos show the toy arm's body rendered through ``camera`` (default: the one
    cams/<name>.json will hold), so a correct calibration scores high."""
    emb = get_embodiment("toyarm")
    src = np.load(TOYARM_ASSETS / "example_trajectory.npz")
    sdir = dump / "evaluation_sessions" / name
    sdir.mkdir(parents=True)
    (sdir / "metadata.yaml").write_text(_metadata(policies, preference))
    for k, (letter, (policy, _, _)) in enumerate(policies.items()):
        edir = sdir / f"{letter}_{policy}"
        edir.mkdir()
        start = 10 + 7 * k + offset
        q, g = src["q"][start : start + T], src["gripper"][start : start + T, 0]
        np.savez(edir / "proprio_and_actions.npz", joint_position=q, gripper_position=g, action=np.zeros((T, 5)))
        traj = Trajectory(tuple(src["joint_names"]), q, 15.0, gripper=g[:, None], gripper_names=("gripper",))
        frames = body_video(emb, traj, camera or _camera(), (W, H))[0]
        for view in ("left_shoulder", "right_shoulder", "wrist"):
            write_video(edir / f"{view}.mp4", frames, 15.0)
    return sdir


def make_dump(root: Path, bad: bool = True) -> tuple[Path, Path]:
    """A dump with the GOOD sessions and (``bad``) one session of each bad kind; returns (dump, cams folder)."""
    dump, cams = root / "DataDump_test", root / "cams"
    cams.mkdir(parents=True)
    (dump / "evaluation_sessions").mkdir(parents=True)
    (dump / "global_metadata.yaml").write_text("total_sessions: 0\n")
    for k, (name, pols, pref) in enumerate(GOOD):
        add_session(dump, name, pols, pref, offset=3 * k)
        save_camera(_camera(), cams / f"{name}.json")
    if bad:
        two = {"A": ("pi0", 1, 1.0), "B": ("pali", 0, 0.0)}
        s = add_session(dump, "bad-video", two, "A")
        (s / "B_pali" / "left_shoulder.mp4").unlink()
        s = add_session(dump, "bad-joints", two, "A")
        np.savez(s / "A_pi0" / "proprio_and_actions.npz", joint_position=np.zeros((T, 5)), gripper_position=np.zeros(T))
        add_session(dump, "bad-single", {"A": ("pi0", 1, 1.0)}, None)
        s = add_session(dump, "bad-meta", two, "A")
        (s / "metadata.yaml").write_text("language_instruction: [unclosed\n")
        s = add_session(dump, "bad-pickle", two, "A")
        np.savez(s / "B_pali" / "proprio_and_actions.npz", data=np.array([{"joint_position": [0.0]}], dtype=object))
        add_session(dump, "no-cal", two, "B")  # no cams/no-cal.json
        for name in ("bad-video", "bad-joints", "bad-single", "bad-meta", "bad-pickle"):
            save_camera(_camera(), cams / f"{name}.json")
    return dump, cams


REASONS = {
    "bad-video": ("layout", r"B_pali/left_shoulder.mp4: field 'file': expected the left_shoulder video"),
    "bad-joints": ("layout", "field 'joint_position': expected numbers of shape (T, 4), found float64 (6, 5)"),
    "bad-single": ("layout", "field 'policies': expected at least two policy episodes (an A/B session), found 1"),
    "bad-meta": ("layout", "metadata.yaml: field 'file': expected valid YAML"),
    "bad-pickle": ("layout", "expected numeric arrays (read without pickle), found object arrays"),
    "no-cal": ("calibration", "no calibration: "),
}


def test_converter_keeps_good_sessions_and_rejects_each_bad_one(tmp_path):
    dump, cams = make_dump(tmp_path)
    out = tmp_path / "study"
    res = convert_roboarena(dump, out, embodiment="toyarm", calibration=cams, fps=15.0)
    assert res.accepted == [name for name, _, _ in GOOD]
    rejected = {r["session"]: r for r in json.loads((out / "rejected.json").read_text())}
    assert sorted(rejected) == sorted(REASONS)
    for name, (stage, text) in REASONS.items():
        assert rejected[name]["stage"] == stage, rejected[name]
        assert text in rejected[name]["reason"], rejected[name]
    assert "6 sessions kept (12 cells, 2 policies, 6 A/B preferences); 6 left out (1 calibration, 5 layout)" in (
        res.summary()
    )
    manifest = load_manifest(out / "manifest.json")  # eval run's own checks pass
    assert manifest.policies == ("pali", "pi0")
    assert len(manifest.cells) == 12 and manifest.sessions == [name for name, _, _ in GOOD]
    by = {(c.session, c.policy): c for c in manifest.cells}
    for name, pols, _ in GOOD:
        for letter, (policy, binary, partial) in pols.items():
            cell = by[(name, policy)]
            assert cell.real_success == binary and cell.info == {"real_partial": partial, "letter": letter}
            assert cell.task == "put the block in the bin"
            assert cell.real_video == (dump / "evaluation_sessions" / name / f"{letter}_{policy}" / "left_shoulder.mp4")
            first = __import__("cv2").imread(str(cell.first_frame))
            assert first.shape == (H, W, 3)
    # A/B preferences mapped from letters to policies: pi0 wins g1, g2, g3; pali wins g4; g5, g6 are ties
    wins = {(p.a, p.b, p.outcome) for p in manifest.real_preferences}
    assert ("pi0", "pali", 2) in wins and ("pali", "pi0", 0) in wins and ("pali", "pi0", 2) in wins
    assert sorted(p.outcome for p in manifest.real_preferences) == [0, 1, 1, 2, 2, 2]
    real = json.loads((out / "real.json").read_text())
    assert real["pi0"]["episodes"] == [1, 1, 0, 0, 1, 0] and real["pi0"]["success_rate"] == 0.5
    assert real["pali"]["success_rate"] == pytest.approx(2 / 6)
    assert real["pali"]["mean_partial"] == pytest.approx((0.4 + 0.2 + 0.1 + 1.0 + 1.0 + 0.0) / 6)


def test_real_board_matches_the_closed_form_of_two_policies(tmp_path):
    """Two policies, 3 wins, 1 loss, 2 ties: the Davidson model is saturated, so its maximum likelihood is
    p(win) = 3/6, p(loss) = 1/6, p(tie) = 2/6: θ_pi0 − θ_pali = ln 3, ν = 2 / (2 √3); Elo = 1500 ± 100 ln 3."""
    dump, cams = make_dump(tmp_path, bad=False)
    out = tmp_path / "study"
    convert_roboarena(dump, out, embodiment="toyarm", calibration=cams, fps=15.0)
    board = json.loads((out / "real_board.json").read_text())["board"]
    elo = {b["policy"]: b["elo"] for b in board["board"]}
    assert elo["pi0"] == pytest.approx(1500 + 100 * math.log(3), abs=1e-4)
    assert elo["pali"] == pytest.approx(1500 - 100 * math.log(3), abs=1e-4)
    assert board["tie_nu"] == pytest.approx(1 / math.sqrt(3), abs=1e-5)
    real = json.loads((out / "real.json").read_text())
    assert real["pi0"]["score"] == pytest.approx(1500 + 100 * math.log(3), abs=1e-4)
    (tmp_path / "wm.json").write_text(json.dumps({"pi0": 0.2, "pali": 0.6}))  # real.json is eval policies' input
    assert oscar_main(["eval", "policies", "--real", str(out / "real.json"), "--wm", str(tmp_path / "wm.json")]) == 0


def test_resampled_trajectory_in_the_study(tmp_path):
    dump, cams = make_dump(tmp_path, bad=False)
    out = tmp_path / "study"
    convert_roboarena(dump, out, embodiment="toyarm", calibration=cams, fps=30.0)
    src = np.load(out / "sessions" / "g1" / "pi0_source.npz")
    res = np.load(out / "sessions" / "g1" / "pi0.npz")
    assert float(res["fps"]) == 30.0 and len(res["q"]) == 2 * (T - 1) + 1
    np.testing.assert_allclose(res["q"][::2], src["q"])  # every other frame is a source step
    np.testing.assert_allclose(res["q"][1::2], (src["q"][:-1] + src["q"][1:]) / 2)  # midpoints in between
    np.testing.assert_allclose(res["gripper"][::2], src["gripper"])


def test_min_score_drops_a_miscalibrated_session(tmp_path):
    dump, cams = make_dump(tmp_path, bad=False)
    moved = perturb_camera(_camera(), shift_m=(0.0, 0.0, 0.0), rotate_deg=(0.0, 12.0, 0.0))
    save_camera(moved, cams / "g3.json")  # the video of g3 was taken by the correct camera
    out = tmp_path / "study"
    res = convert_roboarena(dump, out, embodiment="toyarm", calibration=cams, fps=15.0, min_score=0.5)
    scores = json.loads((out / "sessions.json").read_text())["calibration_scores"]
    assert all(scores[n] > 0.5 for n in scores if n != "g3"), scores
    assert scores["g3"] < 0.5
    assert "g3" not in res.accepted and len(res.accepted) == 5
    (row,) = json.loads((out / "rejected.json").read_text())
    assert row["stage"] == "score" and row["score"] == pytest.approx(scores["g3"])
    assert row["reason"].startswith(f"calibration score {scores['g3']:.3f} below --min-score 0.5")


def test_not_a_dump_fails_up_front_and_rerun_is_safe(tmp_path, capsys):
    (tmp_path / "notadump").mkdir()
    code = oscar_main(["eval", "roboarena", str(tmp_path / "notadump"), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1
    assert "notadump: field 'evaluation_sessions': expected a RoboArena dump: global_metadata.yaml and " in err
    assert err.endswith("found no such folder") and not (tmp_path / "o").exists()
    dump, cams = make_dump(tmp_path / "d", bad=False)
    out = tmp_path / "study"
    args = ["eval", "roboarena", str(dump), "--out", str(out), "--embodiment", "toyarm", "--calibration", str(cams)]
    assert oscar_main(args) == 0

    def contents():  # npz archives hold their write time: compare their arrays
        files = sorted(p for p in out.rglob("*") if p.is_file())
        return {
            p: {k: v.tolist() for k, v in np.load(p).items()} if p.suffix == ".npz" else p.read_bytes() for p in files
        }

    first = contents()
    assert oscar_main(args) == 0  # the same run again: the same files
    assert contents() == first
    assert oscar_main([*args, "--fps", "30"]) == 2  # other settings into the same folder: refused
    assert "expected output of the same inputs and settings" in capsys.readouterr().err
    assert oscar_main([*args[:4], str(tmp_path / "o3"), "--model", "oscar-typo"]) == 2  # not a model: refused
    assert "model 'oscar-typo': expected a zoo name" in capsys.readouterr().err
    assert oscar_main(["eval", "roboarena", str(dump), "--out", str(tmp_path / "o2"), "--embodiment", "toyarm"]) == 1
    rows = json.loads((tmp_path / "o2" / "rejected.json").read_text())
    assert {r["stage"] for r in rows} == {"calibration"} and len(rows) == len(GOOD)
    assert rows[0]["reason"] == "no calibration (pass --calibration DIR with DIR/<session>.json)"


def test_read_session_errors_name_file_field_expected_found(tmp_path):
    dump = tmp_path / "d"
    s = add_session(dump, "s1", {"A": ("pi0", 1, 1.0), "B": ("pali", 0, 0.5)}, "A")
    meta = s / "metadata.yaml"
    kw = dict(view="left_shoulder", joints=4, grippers=1)
    assert read_session(s, **kw).preference == "A"
    meta.write_text(meta.read_text().replace("binary_success: 1", "binary_success: 2"))
    with pytest.raises(RoboArenaError, match=r"metadata.yaml: field 'policies.A.binary_success': expected 0 or 1, "):
        read_session(s, **kw)
    meta.write_text(_metadata({"A": ("pi0", 1, 1.5), "B": ("pali", 0, 0.5)}, "A"))
    with pytest.raises(RoboArenaError, match=r"'policies.A.partial_success': expected a number in \[0, 1\].*1.5"):
        read_session(s, **kw)
    meta.write_text(_metadata({"A": ("pi0", 1, 1.0), "B": ("pali", 0, 0.5)}, "C"))
    with pytest.raises(RoboArenaError, match=r"field 'preference': expected A, B, TIE or null, found 'C'"):
        read_session(s, **kw)
    meta.write_text(_metadata({"A": ("pi0", 1, 1.0), "B": ("pali", 0, 0.5)}, "A"))
    np.savez(s / "A_pi0" / "proprio_and_actions.npz", joint_position=np.zeros((T, 4)))
    with pytest.raises(RoboArenaError, match=r"field 'gripper_position': expected an array .*found no such key"):
        read_session(s, **kw)
    q = np.zeros((T, 4))
    q[2, 1] = np.nan
    np.savez(s / "A_pi0" / "proprio_and_actions.npz", joint_position=q, gripper_position=np.zeros(T))
    with pytest.raises(RoboArenaError, match=r"field 'joint_position': expected finite values, found .* at step 2"):
        read_session(s, **kw)


def test_manifest_real_preferences_checks(tmp_path):
    dump, cams = make_dump(tmp_path, bad=False)
    out = tmp_path / "study"
    convert_roboarena(dump, out, embodiment="toyarm", calibration=cams, fps=15.0)
    path = out / "manifest.json"
    data = json.loads(path.read_text())

    def broken(edit):
        d = json.loads(json.dumps(data))
        edit(d)
        p = out / "m2.json"
        p.write_text(json.dumps(d))
        return p

    with pytest.raises(ManifestError, match=r"real_preferences\[1\]: field 'a': expected one of the manifest's"):
        load_manifest(broken(lambda d: d["real_preferences"][1].update(a="octo")))
    with pytest.raises(ManifestError, match=r"field 'real_preferences': expected real_scores or real_preferences"):
        load_manifest(broken(lambda d: d.update(real_scores={"pi0": 1.0, "pali": 0.0})))
    with pytest.raises(Exception, match=r"real_preferences\[0\]: field 'winner': expected \"a\", \"b\", \"tie\""):
        load_manifest(broken(lambda d: d["real_preferences"][0].update(winner="A+")))


JUDGE = """
def judge(video, clip):
    ok = int(clip.info["letter"] == "A")
    return {"binary": ok, "partial": 100 * ok, "reason": "letter"}
"""


@pytest.mark.slow
def test_three_commands_to_a_finished_report(tmp_path):
    """roboarena -> calibrate score -> eval run, as subprocesses of the installed `oscar`, on a tiny model."""
    import oscar_zoo

    model = tiny_world_model(skeleton_scale=0.05, name="tiny", chunk_frames=5, fps=15.0)
    model_dir = oscar_zoo.export(model, tmp_path / "tiny")
    dump, cams = make_dump(tmp_path)
    study, report_dir = tmp_path / "study", tmp_path / "eval_out"
    (tmp_path / "judge_fns.py").write_text(JUDGE)
    oscar = [sys.executable, "-m", "oscar_core.cli"]

    def run(*argv):
        return subprocess.run([*oscar, *map(str, argv)], capture_output=True, text=True, timeout=600)

    r = run("eval", "roboarena", dump, "--out", study, "--embodiment", "toyarm", "--calibration", cams,
            "--model", model_dir, "--size", "32x16")  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert "6 sessions kept (12 cells, 2 policies, 6 A/B preferences); 6 left out" in r.stdout
    assert float(np.load(study / "sessions" / "g1" / "pi0.npz")["fps"]) == 15.0  # the model card's fps
    r = run("calibrate", "score", "--video", dump / "evaluation_sessions" / "g1" / "A_pi0" / "left_shoulder.mp4",
            "--trajectory", study / "sessions" / "g1" / "pi0_source.npz", "--camera", cams / "g1.json",
            "--embodiment", "toyarm")  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert float(r.stdout.split("score ")[1].split()[0]) > 0.5
    r = run("eval", "run", study / "manifest.json", "--model", model_dir, "--out", report_dir,
            "--judge", f"{tmp_path / 'judge_fns.py'}:judge", "--steps", "1", "--no-progress", "--json")  # fmt: skip
    assert r.returncode == 0, r.stderr
    report = json.loads(r.stdout)
    assert report["counts"]["cells"] == 12 and report["counts"]["verdicts_done"] == 12
    assert report["comparison"]["ranked_by"]["real"] == "real_bradley_terry_elo"
    board = {b["policy"]: b["elo"] for b in report["real_bradley_terry"]["board"]}
    assert board["pi0"] == pytest.approx(1500 + 100 * math.log(3), abs=1e-4)
    rows = {p["policy"]: p for p in report["policies"]}
    assert rows["pi0"]["real_success_rate"] == 0.5 and rows["pi0"]["wm_success_rate"] == 0.5
    assert rows["pi0"]["real_score"] == pytest.approx(1500 + 100 * math.log(3), abs=1e-4)
    assert "Bradley–Terry–Davidson (real pairwise preferences)" in (report_dir / "summary.md").read_text()
    assert (report_dir / "report.html").is_file()
