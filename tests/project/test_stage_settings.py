"""Every setting a stage's fingerprint covers, changed alone, makes the stage refuse or recompute.

For each fingerprinted stage the list of settings is read from the code: the
parts the stage hands to ``oscar_core._util.stage.check_stage`` (or its
per-record fingerprint), recorded on a real run. ``CHANGES`` says how to change
each one through the stage's own API; a part the code fingerprints without an
entry here fails ``test_*_covers_every_fingerprinted_setting``, so a new
setting cannot go untested. Stages: toyworld generate, toyworld rollouts,
``eval benchmark run``, the train latent cache, the batch renderer, the data filter and export
stages, and the per-cell rollout key of ``eval run`` (also the Ray engine with
cells that finish out of order).
"""

import dataclasses
import shutil

import numpy as np
import pytest
from _models import tiny_world_model
from _paths import TOYARM_ASSETS

from oscar_core._util import stage as _stage
from oscar_core._util.stage import StageChanged

#: Parts that name the stage itself: constant, nothing to change.
CONSTANT = {"stage"}


def _recording(monkeypatch) -> list[dict]:
    """Record the parts of every check_stage call (the stage still runs it)."""
    seen: list[dict] = []
    real = _stage.check_stage

    def spy(folder, parts, **kw):
        seen.append(dict(parts))
        return real(folder, parts, **kw)

    monkeypatch.setattr(_stage, "check_stage", spy)
    return seen


def _bump_format(monkeypatch):
    monkeypatch.setattr(_stage, "FORMAT_VERSION", _stage.FORMAT_VERSION + 1)


def _refused_for(key: str, call) -> None:
    with pytest.raises(StageChanged) as err:
        call()
    assert f"{key}: " in str(err.value) or f"{key}." in str(err.value), str(err.value)


# ---------------------------------------------------------------------------------------------- toyworld generate


def _generate_cfg(**kw):
    from oscar_core.toyworld.generate import GenerateConfig

    base = dict(
        embodiments=("toyarm",),
        episodes=1,
        width=16,
        height=16,
        frames=5,
        fps=10.0,
        seed=0,
        shard_size=50,
        supersample=1,
        skeleton=False,
        pick_miss=0.0,
    )
    return GenerateConfig(**{**base, **kw})


GENERATE_CHANGES = {
    "format": lambda mp: ({}, _bump_format(mp)),
    "seed": lambda mp: ({"seed": 1}, None),
    "width": lambda mp: ({"width": 32}, None),
    "height": lambda mp: ({"height": 32}, None),
    "frames": lambda mp: ({"frames": 9}, None),
    "fps": lambda mp: ({"fps": 5.0}, None),
    "shard_size": lambda mp: ({"shard_size": 7}, None),
    "supersample": lambda mp: ({"supersample": 2}, None),
    "skeleton": lambda mp: ({"skeleton": True}, None),
    "pick_miss": lambda mp: ({"pick_miss": 0.5}, None),
}


@pytest.fixture(scope="module")
def generated(tmp_path_factory):
    from oscar_core.plugin.registry import Registry
    from oscar_core.toyworld.generate import generate_clipset

    out = tmp_path_factory.mktemp("gen") / "clips"
    mp = pytest.MonkeyPatch()
    seen = _recording(mp)
    try:
        generate_clipset(_generate_cfg(), out, Registry())
    finally:
        mp.undo()
    return out, seen[0]


def test_generate_covers_every_fingerprinted_setting(generated):
    _, parts = generated
    assert set(parts) - CONSTANT == set(GENERATE_CHANGES)


@pytest.mark.parametrize("key", sorted(GENERATE_CHANGES))
def test_generate_refuses_each_changed_setting(generated, key, tmp_path, monkeypatch):
    from oscar_core.plugin.registry import Registry
    from oscar_core.toyworld.generate import generate_clipset

    out = tmp_path / "clips"
    shutil.copytree(generated[0], out)
    generate_clipset(_generate_cfg(), out, Registry())  # the same settings: resumed, nothing refused
    change, _ = GENERATE_CHANGES[key](monkeypatch)
    _refused_for(key, lambda: generate_clipset(_generate_cfg(**change), out, Registry()))


# ---------------------------------------------------------------------------------------------- toyworld rollouts


@pytest.fixture(scope="module")
def tiny_model():
    import torch

    return tiny_world_model(name="tiny", chunk_frames=5, fps=10.0, empty_prompt=torch.zeros(1, 1, 48))


def _rollouts(model, clips, out, **kw):
    from oscar_core.model.sampler import SamplerConfig
    from oscar_core.toyworld.rollouts import write_rollouts

    base = dict(condition="true", split=None, limit=None, sampler=SamplerConfig(steps=1), seed=0, model_id="tiny@a")
    return write_rollouts(model, clips, out, **{**base, **kw})


def _other_card(model):
    return dataclasses.replace(model.card, name="tiny-2")


ROLLOUT_CHANGES = {
    "format": lambda mp, m, c: ({}, _bump_format(mp)),
    "model": lambda mp, m, c: ({"model_id": "tiny@b"}, None),
    "card": lambda mp, m, c: ({}, mp.setattr(m, "card", _other_card(m))),
    "condition": lambda mp, m, c: ({"condition": "zero"}, None),
    "split": lambda mp, m, c: ({"split": "train"}, None),
    "limit": lambda mp, m, c: ({"limit": 1}, None),
    "clips": lambda mp, m, c: ({"clipset": c}, None),  # the same clips at another path
    "sampler": lambda mp, m, c: (
        {"sampler": __import__("oscar_core.model.sampler", fromlist=["x"]).SamplerConfig(steps=2)},
        None,
    ),
    "seed": lambda mp, m, c: ({"seed": 1}, None),
}


@pytest.fixture(scope="module")
def rolled(generated, tiny_model, tmp_path_factory):
    root = tmp_path_factory.mktemp("roll")
    mp = pytest.MonkeyPatch()
    seen = _recording(mp)
    try:
        summary = _rollouts(tiny_model, generated[0], root / "preds")
    finally:
        mp.undo()
    assert summary["written"] == 1
    return root / "preds", seen[0]


def test_toyworld_rollouts_cover_every_fingerprinted_setting(rolled):
    assert set(rolled[1]) - CONSTANT == set(ROLLOUT_CHANGES)


@pytest.mark.parametrize("key", sorted(ROLLOUT_CHANGES))
def test_toyworld_rollouts_refuse_each_changed_setting(rolled, generated, tiny_model, key, tmp_path, monkeypatch):
    out = tmp_path / "preds"
    shutil.copytree(rolled[0], out)
    assert _rollouts(tiny_model, generated[0], out)["kept"] == 1  # the same settings: resumed
    moved = tmp_path / "clips-copy"
    shutil.copytree(generated[0], moved)
    change, _ = ROLLOUT_CHANGES[key](monkeypatch, tiny_model, moved)
    clips = change.pop("clipset", generated[0])
    _refused_for(key, lambda: _rollouts(tiny_model, clips, out, **change))


# ---------------------------------------------------------------------------------------------- benchmark run


def _bench(clips, path, frames=5):
    from oscar_core.evaluation.benchmark_set import build_benchmark_set, load_benchmark_set
    from oscar_core.plugin.registry import Registry

    build_benchmark_set([clips], path, 1, frames=frames, split=None, registry=Registry())
    return load_benchmark_set(path)


def _run_bench(model, bench, out, **kw):
    from oscar_core.evaluation.benchmark_run import run_benchmark
    from oscar_core.model.sampler import SamplerConfig

    base = dict(sampler=SamplerConfig(steps=1), seed=0, prompt="empty", model_id="tiny@a")
    return run_benchmark(model, bench, out, **{**base, **kw})


BENCH_CHANGES = {
    "format": lambda mp, m, c, t: ({}, _bump_format(mp)),
    "model": lambda mp, m, c, t: ({"model_id": "tiny@b"}, None),
    "card": lambda mp, m, c, t: ({}, mp.setattr(m, "card", _other_card(m))),
    "set": lambda mp, m, c, t: ({"bench": _bench(c, t / "other.json")}, None),  # the same clips at another path
    "frames": lambda mp, m, c, t: ({"bench": _bench(c, t / "short.json", frames=3)}, None),  # comes with its set
    "sampler": lambda mp, m, c, t: (
        {"sampler": __import__("oscar_core.model.sampler", fromlist=["x"]).SamplerConfig(steps=2)},
        None,
    ),
    "seed": lambda mp, m, c, t: ({"seed": 1}, None),
    "prompt": lambda mp, m, c, t: ({"prompt": "clip"}, None),
}


@pytest.fixture(scope="module")
def benched(generated, tiny_model, tmp_path_factory):
    root = tmp_path_factory.mktemp("bench")
    bench = _bench(generated[0], root / "set.json")
    mp = pytest.MonkeyPatch()
    seen = _recording(mp)
    try:
        assert _run_bench(tiny_model, bench, root / "run")["written"] == 1
    finally:
        mp.undo()
    return bench, root / "run", seen[0]


def test_benchmark_run_covers_every_fingerprinted_setting(benched):
    assert set(benched[2]) - CONSTANT == set(BENCH_CHANGES)


@pytest.mark.parametrize("key", sorted(BENCH_CHANGES))
def test_benchmark_run_refuses_each_changed_setting(benched, generated, tiny_model, key, tmp_path, monkeypatch):
    bench, run, _ = benched
    out = tmp_path / "run"
    shutil.copytree(run, out)
    assert _run_bench(tiny_model, bench, out)["kept"] == 1  # the same settings: resumed
    moved = tmp_path / "clips-copy"
    shutil.copytree(generated[0], moved)
    change, _ = BENCH_CHANGES[key](monkeypatch, tiny_model, moved, tmp_path)
    other = change.pop("bench", bench)
    _refused_for(key, lambda: _run_bench(tiny_model, other, out, **change))


# ---------------------------------------------------------------------------------------------- train latent cache


@pytest.fixture(scope="module")
def cache_src(tmp_path_factory):
    from oscar_core.plugin.registry import Registry
    from oscar_core.toyworld.generate import generate_clipset

    out = tmp_path_factory.mktemp("cachesrc") / "clips"
    generate_clipset(_generate_cfg(frames=9, skeleton=True), out, Registry())
    return out


def _vae(seed=0):
    from oscar_core.model.tiny import build_tiny_vae
    from oscar_core.model.vae import VideoVAE

    return VideoVAE(build_tiny_vae(seed=seed))


CACHE_CHANGES = {
    "format": lambda mp, src: ({}, _bump_format(mp)),
    "source": lambda mp, src: ({"src": src}, None),
    "vae": lambda mp, src: ({"vae_name": "other-vae"}, None),
    "vae_weights": lambda mp, src: ({"vae": _vae(seed=1)}, None),
    "window": lambda mp, src: ({"window": 5}, None),
    "stride": lambda mp, src: ({"stride": 4}, None),
    "split": lambda mp, src: ({"split": "train"}, None),
    "condition": lambda mp, src: ({"condition": "capsules"}, None),
}


def _cache(src, out, **kw):
    from oscar_core.train.cache import cache_latents

    base = dict(vae=_vae(), window=9, vae_name="tiny-vae", log=lambda m: None)
    base.update(kw)
    return cache_latents(src, out, **base)


@pytest.fixture(scope="module")
def cached(cache_src, tmp_path_factory):
    out = tmp_path_factory.mktemp("cache") / "latents"
    mp = pytest.MonkeyPatch()
    seen = _recording(mp)
    try:
        _cache(cache_src, out)
    finally:
        mp.undo()
    return out, seen[0]


def test_latent_cache_covers_every_fingerprinted_setting(cached):
    assert set(cached[1]) - CONSTANT == set(CACHE_CHANGES)


@pytest.mark.parametrize("key", sorted(CACHE_CHANGES))
def test_latent_cache_refuses_each_changed_setting(cached, cache_src, key, tmp_path, monkeypatch):
    out = tmp_path / "latents"
    shutil.copytree(cached[0], out)
    _cache(cache_src, out)  # the same settings: resumed
    moved = tmp_path / "src-copy"
    shutil.copytree(cache_src, moved)
    change, _ = CACHE_CHANGES[key](monkeypatch, moved)
    src = change.pop("src", cache_src)
    _refused_for(key, lambda: _cache(src, out, **change))


# ---------------------------------------------------------------------------------------------- batch render


def _render_spec(tmp_path, **kw):
    from oscar_core.render.batch import EpisodeSpec

    base = dict(
        embodiment="toyarm",
        trajectory=str(tmp_path / "t.npz"),
        camera=str(tmp_path / "c.json"),
        out=str(tmp_path / "v" / "t.mkv"),
        size=(32, 32),
    )
    return EpisodeSpec(**{**base, **kw})


def _render_inputs(tmp_path):
    from oscar_core import load_trajectory, save_trajectory

    save_trajectory(load_trajectory(TOYARM_ASSETS / "example_trajectory.npz").time_slice(0, 3), tmp_path / "t.npz")
    shutil.copy(TOYARM_ASSETS / "example_camera.json", tmp_path / "c.json")


def _edit_trajectory(tmp_path):
    from oscar_core import load_trajectory, save_trajectory

    save_trajectory(load_trajectory(TOYARM_ASSETS / "example_trajectory.npz").time_slice(5, 8), tmp_path / "t.npz")
    return {}, {}


def _edit_camera(tmp_path):
    import json

    cam = json.loads((tmp_path / "c.json").read_text())
    cam["intrinsics"]["fx"] = float(cam["intrinsics"]["fx"]) * 1.1
    (tmp_path / "c.json").write_text(json.dumps(cam))
    return {}, {}


def _one_file_plugin(tmp_path):
    plugin = tmp_path / "noop_plugin.py"
    plugin.write_text("# a plugin file that registers nothing\n")
    return {}, {"plugin_paths": (str(plugin),)}


#: part -> (tmp_path -> (EpisodeSpec changes, RenderOptions changes))
RENDER_CHANGES = {
    "format_version": None,  # the bumped FORMAT_VERSION (monkeypatched in the test)
    "embodiment": lambda p: ({"embodiment": "toyarm_alias"}, {}),
    "trajectory": _edit_trajectory,
    "camera": _edit_camera,
    "size": lambda p: ({"size": (48, 32)}, {}),
    "fps": lambda p: ({"fps": 5.0}, {}),
    "resize": lambda p: ({"resize": "stretch"}, {}),
    "format": lambda p: ({"format": "mkv"}, {}),
    "condition": lambda p: ({"condition": "capsules"}, {}),
    "preset": lambda p: ({}, {"preset": "veryfast"}),
    "crf": lambda p: ({}, {"crf": 30}),
    "yuv": lambda p: ({}, {"yuv": "swscale"}),
    "strict": lambda p: ({}, {"strict": True}),
    "device": None,  # one device here: checked on the parts only
    "plugin_paths": _one_file_plugin,
    "condition_style": lambda p: ({}, {"condition_style": {"gripper_radius_open": 27}}),  # a part only when given
}


def test_batch_render_covers_every_fingerprinted_setting(tmp_path):
    from oscar_core.render.batch import RenderOptions, episode_parts

    _render_inputs(tmp_path)
    styled = RenderOptions(condition_style={"gripper_radius_open": 27})
    assert set(episode_parts(_render_spec(tmp_path), styled)) == set(RENDER_CHANGES)
    # without a style the parts are those records written before the option had (they keep matching)
    assert set(episode_parts(_render_spec(tmp_path), RenderOptions())) == set(RENDER_CHANGES) - {"condition_style"}


@pytest.mark.parametrize("key", sorted(RENDER_CHANGES))
def test_batch_render_redoes_an_episode_for_each_changed_setting(key, tmp_path, monkeypatch):
    from oscar_core.render.batch import RenderOptions, episode_parts, render_many

    _render_inputs(tmp_path)
    spec, opts = _render_spec(tmp_path), RenderOptions()
    assert [r.skipped for r in render_many([spec], opts, resume=True)] == [False]
    assert [r.skipped for r in render_many([spec], opts, resume=True)] == [True]  # the same: skipped
    if key == "device":  # a CUDA device cannot be used here: the part it feeds changes, so the record would not match
        other = episode_parts(spec, dataclasses.replace(opts, device="cuda:0"))
        assert other["device"] == "cuda" and _stage.fingerprint(other) != _stage.fingerprint(episode_parts(spec, opts))
        return
    if key == "format_version":
        _bump_format(monkeypatch)
    else:
        if key == "embodiment":  # the same robot under another registered name
            import oscar_toyarm

            class Alias(oscar_toyarm.ToyArm):
                name = "toyarm_alias"

            from oscar_core.plugin import registry as reg

            real_get = reg.Registry.get
            monkeypatch.setattr(
                reg.Registry, "get", lambda self, n: Alias() if n == "toyarm_alias" else real_get(self, n)
            )
        s_change, o_change = RENDER_CHANGES[key](tmp_path)
        spec, opts = dataclasses.replace(spec, **s_change), dataclasses.replace(opts, **o_change)
    (result,) = render_many([spec], opts, resume=True)
    assert not result.skipped, (key, result)
    if key == "embodiment":  # the calibration names its robot: the episode is redone, and refused naming the field
        assert not result.ok and "field 'embodiment': expected 'toyarm_alias', found 'toyarm'" in result.error
    else:
        assert result.ok, (key, result)


# ---------------------------------------------------------------------------------------------- data stages


def _filter_value(name, value):
    """Another valid value of FilterConfig field ``name``."""
    if isinstance(value, bool):
        return not value
    if isinstance(value, int):
        return value + 1
    if isinstance(value, float):
        return value * 1.5 if value else 0.5
    raise AssertionError(f"FilterConfig.{name}: no rule to change a {type(value).__name__}; add one here")


@pytest.fixture(scope="module")
def data_run(tmp_path_factory):
    from _datasets import write_episode

    from oscar_core.cli import main

    root = tmp_path_factory.mktemp("datarun")
    write_episode(root / "src", "ep0", seed=0)
    run = root / "run"
    common = ["--workers", "1", "--no-progress"]
    assert main(["data", "ingest", str(root / "src"), "--reader", "npz", "--out", str(run), *common]) == 0
    assert main(["data", "filter", str(run), *common]) == 0
    return run


def _filter_fields():
    from oscar_core.data.filters import FilterConfig

    return sorted(FilterConfig().to_dict())


def test_filter_fingerprint_holds_every_filter_setting(data_run):
    from oscar_core.data.engine import read_fingerprint
    from oscar_core.data.filters import FilterConfig

    settings = read_fingerprint(str(data_run / "filter"))["parts"]["settings"]
    assert set(settings) == set(FilterConfig().to_dict()) | {"plugin_paths"}
    assert {f.name for f in dataclasses.fields(FilterConfig)} == set(FilterConfig().to_dict())


@pytest.mark.parametrize("field", _filter_fields())
def test_filter_recomputes_for_each_changed_setting(data_run, field, tmp_path):
    from oscar_core.data.engine import StageRecomputed
    from oscar_core.data.filters import FilterConfig
    from oscar_core.data.run import run_filter

    run = tmp_path / "run"
    shutil.copytree(data_run, run)
    same = run_filter(str(run), FilterConfig(), workers=1, progress=False)
    assert same.skipped and not same.processed
    cfg = dataclasses.replace(FilterConfig(), **{field: _filter_value(field, getattr(FilterConfig(), field))})
    with pytest.warns(StageRecomputed, match=rf"settings\.{field}: "):
        res = run_filter(str(run), cfg, workers=1, progress=False)
    assert res.processed and not res.skipped


EXPORT_CHANGES = {
    "out": None,
    "size": {"size": (32, 32)},
    "render_skeleton": {"render_skeleton": True},
    "video_codec": {"video_codec": "h264"},
    "plugin_paths": "plugin",
}


def test_export_fingerprint_holds_every_export_setting(data_run, tmp_path):
    from oscar_core.data.engine import read_fingerprint
    from oscar_core.data.run import run_export

    run = tmp_path / "run"
    shutil.copytree(data_run, run)
    run_export(str(run), str(tmp_path / "clips"), workers=1, progress=False)
    assert set(read_fingerprint(str(run / "export"))["parts"]["settings"]) == set(EXPORT_CHANGES)


@pytest.mark.parametrize("key", sorted(EXPORT_CHANGES))
def test_export_recomputes_for_each_changed_setting(data_run, key, tmp_path):
    from oscar_core.data.engine import StageRecomputed
    from oscar_core.data.run import run_export

    run = tmp_path / "run"
    shutil.copytree(data_run, run)
    base = dict(workers=1, progress=False)
    run_export(str(run), str(tmp_path / "clips"), **base)
    assert run_export(str(run), str(tmp_path / "clips"), **base).skipped  # the same: resumed
    out, change = str(tmp_path / "clips"), EXPORT_CHANGES[key]
    if key == "out":
        out, change = str(tmp_path / "clips-2"), {}
    elif key == "plugin_paths":
        plugin = tmp_path / "noop_plugin.py"
        plugin.write_text("# a plugin file that registers nothing\n")
        change = {"plugin_paths": (str(plugin),)}
    with pytest.warns(StageRecomputed, match=rf"settings\.{key}: "):
        res = run_export(str(run), out, **base, **change)
    assert res.processed and not res.skipped


# ---------------------------------------------------------------------------------------------- eval run: rollout key


def _cell(tmp_path):
    from oscar_core.evaluation.manifest import Cell

    for name in ("first.png", "traj.npz", "cam.json", "embeds.safetensors"):
        (tmp_path / name).write_bytes(name.encode())
    return Cell(
        "s",
        "p",
        "task",
        "toyarm",
        tmp_path / "first.png",
        tmp_path / "traj.npz",
        tmp_path / "cam.json",
        0,
        prompt_embeds=tmp_path / "embeds.safetensors",
    )


def _rollout_key_args():
    import inspect

    from oscar_core.evaluation.loop import rollout_key

    return [p for p in inspect.signature(rollout_key).parameters if p != "cell"]


#: Cell fields a rollout depends on (the others name the cell or are read by the judge only).
ROLLOUT_CELL_FIELDS = {"first_frame", "trajectory", "camera", "prompt_embeds", "seed", "embodiment"}
NOT_ROLLOUT_INPUTS = {"session", "policy", "task", "row", "real_success", "real_video", "info"}


def test_every_cell_field_is_a_rollout_input_or_named_as_not_one():
    from oscar_core.evaluation.manifest import Cell

    assert {f.name for f in dataclasses.fields(Cell)} == ROLLOUT_CELL_FIELDS | NOT_ROLLOUT_INPUTS


@pytest.mark.parametrize("name", sorted(set(_rollout_key_args()) | ROLLOUT_CELL_FIELDS))
def test_eval_run_rollout_key_changes_with_each_input_alone(name, tmp_path):
    from oscar_core.evaluation.loop import rollout_key

    cell = _cell(tmp_path)
    args = dict(model_id="m@1", sampler={"steps": 1}, chunk_frames=5, size=(32, 16), fps=15.0)
    assert set(args) == set(_rollout_key_args())
    key = rollout_key(cell, **args)
    assert rollout_key(cell, **args) == key
    if name in args:
        other = {"model_id": "m@2", "sampler": {"steps": 2}, "chunk_frames": 9, "size": (64, 32), "fps": 10.0}[name]
        changed = rollout_key(cell, **{**args, name: other})
    elif name in ("seed", "embodiment"):
        changed = rollout_key(dataclasses.replace(cell, **{name: 1 if name == "seed" else "franka"}), **args)
    else:  # a file input: same path, other bytes
        getattr(cell, name).write_bytes(b"other bytes")
        changed = rollout_key(cell, **args)
    assert changed != key


# ---------------------------------------------------------------------------------------------- Ray: out of order


@pytest.mark.slow
def test_ray_engine_records_cells_that_finish_out_of_order_under_their_own_names(tmp_path):
    """Two Ray workers, one cell each at a time: the first cell is ten chunks long, the others one, so the others
    come back first. Every cell's record and video must still be its own (equal to the in-process run's)."""
    pytest.importorskip("ray", reason='ray is not installed (pip install "oscar-wm[ray]")')
    from _studies import make_study

    import oscar_zoo
    from oscar_core.evaluation.loop import run_evaluation
    from oscar_core.media.video import read_video
    from oscar_core.metrics import ProgrammaticJudge
    from oscar_core.model import SamplerConfig

    model = tiny_world_model(skeleton_scale=0.05, name="tiny", chunk_frames=5, fps=15.0)
    mdir = oscar_zoo.export(model, tmp_path / "tiny")
    manifest = make_study(tmp_path / "study", frames=41)
    for npz in sorted((tmp_path / "study").glob("*.npz")):
        d = dict(np.load(npz))
        if npz.name != "s1_good.npz":  # every cell but the first: one chunk (5 frames)
            d["q"], d["gripper"] = d["q"][:5], d["gripper"][:5]
        else:  # the first: 100 chunks (401 frames, its 41 played back and forth), far longer than a worker's start
            index = np.resize(np.r_[np.arange(41), np.arange(39, 0, -1)], 401)
            d["q"], d["gripper"] = d["q"][index], d["gripper"][index]
            real = np.load(tmp_path / "study" / "real_s1_good.npy")
            np.save(tmp_path / "study" / "real_s1_good.npy", real[np.resize(np.arange(len(real)), 401)])
        np.savez(npz, **d)
    judge = ProgrammaticJudge(lambda video, clip: {"binary": clip.info["wm"], "partial": 50, "reason": "ok"})
    kwargs = dict(model_spec=str(mdir), sampler=SamplerConfig(steps=1), judge=judge, batch_cells=1)
    local = run_evaluation(manifest, tmp_path / "local", log=lambda m: None, **kwargs)
    said: list[str] = []
    import ray

    # a cluster of its own with exactly two CPUs: an earlier test's actors (which give their CPUs back
    # asynchronously) cannot leave this run with one worker; the engine joins the running cluster
    ray.shutdown()
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False)
    try:
        ray_run = run_evaluation(manifest, tmp_path / "ray", engine="ray", workers=2, log=said.append, **kwargs)
    finally:
        ray.shutdown()
    order = [int(m.split("]")[0].strip("[").split("/")[0]) - 1 for m in said if "rolled out" in m]
    assert sorted(order) == list(range(6)), order
    for a, b in zip(local.report["cells"], ray_run.report["cells"]):
        assert a["cell"] == b["cell"] and a["frames"] == b["frames"] and a["wm_success"] == b["wm_success"]
        va, vb = read_video(tmp_path / "local" / a["video"]), read_video(tmp_path / "ray" / b["video"])
        assert va.shape == vb.shape and np.abs(va.astype(int) - vb.astype(int)).max() <= 1, a["cell"]
    assert [c["frames"] for c in ray_run.report["cells"]] == [401, 5, 5, 5, 5, 5]
    assert not [m for m in said if "instead of" in m], said  # both workers started
    if order == sorted(order):  # the second worker started only after the long cell's 100 chunks
        pytest.skip(f"the cells did not finish out of order here ({order}): records checked, order not")
    assert order.index(0) > order.index(1)


# ---------------------------------------------------------------------------------------------- data ingest

#: What ingest's fingerprint holds; each is changed alone below, except where the reason says why not.
INGEST_PARTS = {
    "input.source": "tested",
    "input.reader": "no second reader reads the npz layout",
    "input.listing": "tested in test_stage_resume (the dataset grew)",
    "settings.plugin_paths": "tested",
    "input.ids": "the episodes of the listing (changes with it)",
    "input.shard_size": "tested",
    "settings.reader_options": "the npz reader takes no options",
}


def test_ingest_fingerprint_holds_what_the_tests_name(data_run):
    from oscar_core.data.engine import read_fingerprint

    parts = read_fingerprint(str(data_run / "ingest"))["parts"]
    assert {f"{k}.{v}" for k in ("input", "settings") for v in parts[k]} == set(INGEST_PARTS)


@pytest.mark.parametrize("key", [k for k, why in INGEST_PARTS.items() if why == "tested"])
def test_ingest_recomputes_for_each_changed_setting(data_run, key, tmp_path):
    from oscar_core.data.engine import StageRecomputed
    from oscar_core.data.run import run_ingest

    run = tmp_path / "run"
    shutil.copytree(data_run, run)
    src = str(data_run.parent / "src")
    assert run_ingest(src, "npz", str(run), workers=1, progress=False).skipped  # the same: resumed
    kw = {}
    if key == "input.source":  # the same episodes in another folder
        shutil.copytree(data_run.parent / "src", tmp_path / "src2")
        src = str(tmp_path / "src2")
    elif key == "input.shard_size":
        kw = {"shard_size": 7}
    else:
        plugin = tmp_path / "noop_plugin.py"
        plugin.write_text("# a plugin file that registers nothing\n")
        kw = {"plugin_paths": (str(plugin),)}
    with pytest.warns(StageRecomputed, match=rf"{key.split('.')[-1]}: "):
        res = run_ingest(src, "npz", str(run), workers=1, progress=False, **kw)
    assert res.processed and not res.skipped
