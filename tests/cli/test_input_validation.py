"""Bad input is refused before work starts: config fields type-checked, sampler settings finite, sizes bounded by
memory, rollout outputs checked before any weights load, and toy-world rows over different clips refused."""

from __future__ import annotations

import argparse
import math
import sys

import numpy as np
import pytest
from _paths import TOYARM_ASSETS

from oscar_core.errors import OscarError
from oscar_core.model.errors import ModelInputError
from oscar_core.model.sampler import SamplerConfig
from oscar_core.train.config import TrainConfigError, config_from_dict, load_config

TRAJ, CAM = TOYARM_ASSETS / "example_trajectory.npz", TOYARM_ASSETS / "example_camera.json"  # 81 frames, 640x360


def _cfg(**sections):
    data = {"data": {"clips": ["clips/a"]}}
    for key, value in sections.items():
        data[key] = {**data.get(key, {}), **value} if isinstance(value, dict) else value
    return data


# ------------------------------------------------------------------ training config


@pytest.mark.parametrize(
    "fields, name, expected, found",
    [
        (dict(model={"compile": "nope"}), "model.compile", "true or false", "str 'nope'"),
        (dict(export="yes"), "export", "true or false", "str 'yes'"),
        (dict(log={"tensorboard": 1}), "log.tensorboard", "true or false", "int 1"),
        (dict(optim={"warmup_steps": 2.5}), "optim.warmup_steps", "an integer", "float 2.5"),
        (dict(steps=True), "steps", "an integer", "bool True"),
        (dict(data={"clips": ["c"], "window": 9.0}), "data.window", "an integer", "float 9.0"),
        (dict(data={"clips": ["c"], "sources": "droid"}), "data.sources", "a list", "str 'droid'"),
        (dict(data={"clips": "clips/a"}), "data.clips", "a list", "str 'clips/a'"),
        (dict(data={"clips": ["c"], "sources": ["droid", 3]}), "data.sources[1]", "a string", "int 3"),
        (dict(optim={"lr": "fast"}), "optim.lr", "a number", "str 'fast'"),
        (dict(optim={"lr": float("nan")}), "optim.lr", "a finite number", "nan"),
        (dict(flow={"shift": float("inf")}), "flow.shift", "a finite number", "inf"),
        (dict(optim={"betas": [0.9, "x"]}), "optim.betas[1]", "a number", "str 'x'"),
        (dict(run_dir=None), "run_dir", "a string", "null"),
    ],
)
def test_config_fields_are_type_checked(fields, name, expected, found):
    with pytest.raises(TrainConfigError) as err:
        config_from_dict(_cfg(**fields), "c.yaml")
    assert str(err.value) == f"c.yaml: field '{name}': expected {expected}, found {found}"


@pytest.mark.parametrize("value", [True, False])
def test_a_renamed_key_is_refused_naming_the_key_to_write_instead(tmp_path, value):
    p = tmp_path / "c.yaml"
    p.write_text(f"data: {{clips: [x]}}\nmodel: {{gradient_checkpointing: {str(value).lower()}}}\n")
    with pytest.raises(TrainConfigError) as err:
        load_config(p)
    assert str(err.value) == (
        f"{p}: field 'model.gradient_checkpointing': expected the top-level key "
        "activation_checkpointing instead (full for true, auto or none for false), found "
        f"model.gradient_checkpointing: {value!r}"
    )
    p.write_text("data: {clips: [x]}\n")  # the same through --set
    with pytest.raises(
        TrainConfigError,
        match="'model.gradient_checkpointing': expected the top-level key activation_checkpointing instead",
    ):
        load_config(p, {"model.gradient_checkpointing": value})


def test_config_values_of_the_right_type_pass_and_yaml_exponents_are_numbers(tmp_path):
    cfg = config_from_dict(
        _cfg(
            data={"clips": ["a"], "sources": ["droid"]},
            optim={"lr": "1e-4", "warmup_steps": 3},
            model={"compile": True},
            steps=7,
        )
    )
    assert cfg.optim.lr == 1e-4 and isinstance(cfg.optim.lr, float)  # PyYAML reads 1e-4 as a string
    assert (cfg.data.sources, cfg.optim.warmup_steps, cfg.model.compile, cfg.steps) == (["droid"], 3, True, 7)
    assert config_from_dict(_cfg(optim={"lr": 1})).optim.lr == 1.0  # an integer where a number is asked is fine
    assert config_from_dict(_cfg(data={"clips": ["a"], "sources": None})).data.sources is None
    p = tmp_path / "c.yaml"
    p.write_text("data: {clips: [x]}\nmodel: {compile: nope}\n")
    with pytest.raises(
        TrainConfigError,
        match=r"c.yaml: field 'model.compile': expected true or "
        r"false, found str 'nope'",
    ):
        load_config(p)
    p.write_text("data: {clips: [x]}\n")
    assert load_config(p, {"optim.lr": "2e-5"}).optim.lr == 2e-5


def test_train_cli_refuses_a_bad_override_before_building_anything(tmp_path, capsys):
    from oscar_core.cli import main

    p = tmp_path / "c.yaml"
    p.write_text(f"run_dir: {tmp_path / 'run'}\ndata: {{clips: [{tmp_path / 'missing'}]}}\n")
    assert main(["train", str(p), "--set", "data.sources=droid"]) == 2
    assert "field 'data.sources': expected a list, found str 'droid'" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()


# ------------------------------------------------------------------ sampler


@pytest.mark.parametrize(
    "kwargs, field",
    [
        (dict(guidance=float("nan")), "guidance"),
        (dict(guidance=float("inf")), "guidance"),
        (dict(guidance=-1.0), "guidance"),
        (dict(action_guidance=float("nan")), "action_guidance"),
        (dict(action_guidance=-0.5), "action_guidance"),
        (dict(steps=0), "steps"),
        (dict(steps=-3), "steps"),
        (dict(steps=2.5), "steps"),
        (dict(steps=True), "steps"),
        (dict(shift=float("nan")), "shift"),
        (dict(shift=float("inf")), "shift"),
        (dict(cond_timestep=float("nan")), "cond_timestep"),
    ],
)
def test_sampler_refuses_non_finite_or_negative_settings(kwargs, field):
    with pytest.raises(ModelInputError, match=f"sampler {field}: expected"):
        SamplerConfig(**kwargs)


def test_sampler_accepts_the_documented_settings():
    assert SamplerConfig(guidance=0.0, steps=1).guidance == 0.0
    assert SamplerConfig(guidance=None, action_guidance=2.0).action_guidance == 2.0
    assert SamplerConfig(steps=np.int64(4)).steps == 4


# ------------------------------------------------------------------ rollout: inputs before weights


def _rollout(capsys, monkeypatch, tmp_path, out, *extra):
    """`oscar rollout` whose model loader fails the test if it is reached."""
    import cv2

    import oscar_zoo
    from oscar_core.model.cli import add_model_parsers

    def load(*a, **k):
        raise AssertionError("weights were loaded before the inputs were checked")

    monkeypatch.setattr(oscar_zoo, "load", load)
    first = tmp_path / "first.png"
    cv2.imwrite(str(first), np.zeros((360, 640, 3), np.uint8))
    parser = argparse.ArgumentParser(prog="oscar")
    add_model_parsers(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(
        [
            str(a)
            for a in (
                "rollout",
                "--model",
                "tiny",
                "--embodiment",
                "toyarm",
                "--first-frame",
                first,
                "--trajectory",
                TRAJ,
                "--camera",
                CAM,
                "--out",
                out,
                *extra,
            )
        ]
    )
    with pytest.raises((OscarError, ValueError)) as err:
        args.func(args)
    return str(err.value)


def test_rollout_checks_its_outputs_before_loading_weights(capsys, monkeypatch, tmp_path):
    msg = _rollout(capsys, monkeypatch, tmp_path, tmp_path / "no" / "such" / "v.mp4")
    assert "v.mp4: cannot write output" in msg and "does not exist" in msg
    msg = _rollout(capsys, monkeypatch, tmp_path, tmp_path / "v.avi")
    assert "unsupported suffix '.avi'" in msg
    (tmp_path / "v_side.mp4").mkdir()
    msg = _rollout(capsys, monkeypatch, tmp_path, tmp_path / "v.mp4")  # the default side-by-side path is a folder
    assert "v_side.mp4: cannot write output: it is a folder" in msg
    msg = _rollout(capsys, monkeypatch, tmp_path, tmp_path / "w.mp4", "--size", "100000")
    assert "--size: expected WIDTHxHEIGHT" in msg


@pytest.mark.parametrize(
    "flag, value, expected",
    [
        ("--guidance", "nan", "expected a finite number, found 'nan'"),
        ("--guidance", "inf", "expected a finite number, found 'inf'"),
        ("--guidance", "-2", "expected a number >= 0, found -2"),
        ("--steps", "0", "expected an integer >= 1, found 0"),
        ("--steps", "2.5", "expected an integer, found '2.5'"),
        ("--shift", "0", "expected a number > 0, found 0"),
    ],
)
def test_rollout_options_are_refused_by_the_parser(capsys, monkeypatch, tmp_path, flag, value, expected):
    with pytest.raises(SystemExit) as exit_:
        _rollout(capsys, monkeypatch, tmp_path, tmp_path / "v.mp4", flag, value)
    assert exit_.value.code == 2
    assert f"argument {flag}: {expected}" in capsys.readouterr().err


@pytest.mark.parametrize(
    "argv, expected",
    [
        (["data", "filter", "r", "--workers", "0"], "argument --workers: expected an integer >= 1, found 0"),
        (["data", "filter", "r", "--shard-size", "-4"], "argument --shard-size: expected an integer >= 1, found -4"),
        (["data", "dedup", "r", "--siglip", "s", "--cosine", "nan"], "argument --cosine: expected a finite number"),
        (["data", "dedup", "r", "--siglip", "s", "--cosine", "1.5"], "argument --cosine: expected a number <= 1"),
        (
            ["data", "caption", "r", "--endpoint", "e", "--model", "m", "--fps", "0"],
            "argument --fps: expected a number > 0",
        ),
        (
            ["data", "caption", "r", "--endpoint", "e", "--model", "m", "--budget", "-1"],
            "argument --budget: expected an integer >= 0, found -1",
        ),
        (["render", "--alpha", "2"], "argument --alpha: expected a number <= 1, found 2"),
        (
            ["toyworld", "generate", "--embodiments", "kuka", "--episodes", "0", "--out", "o"],
            "argument --episodes: expected an integer >= 1, found 0",
        ),
        (
            ["toyworld", "rollout", "m", "c", "--out", "o", "--guidance", "inf"],
            "argument --guidance: expected a finite",
        ),
        (["train", "--cache-latents", "c", "--window", "2.5"], "argument --window: expected an integer, found '2.5'"),
        (["eval", "run", "--guidance", "nan"], "argument --guidance: expected a finite number, found 'nan'"),
        (["eval", "run", "--steps", "0"], "argument --steps: expected an integer >= 1, found 0"),
        (["eval", "judge", "--concurrency", "0"], "argument --concurrency: expected an integer >= 1, found 0"),
        (["eval", "judge", "--timeout", "-1"], "argument --timeout: expected a number > 0, found -1"),
        (["eval", "video", "--frames", "-1"], "argument --frames: expected an integer >= 0, found -1"),
    ],
)
def test_cli_options_are_range_checked_by_the_parser(capsys, argv, expected):
    from oscar_core.cli import build_parser

    with pytest.raises(SystemExit) as exit_:
        build_parser().parse_args(argv)
    assert exit_.value.code == 2
    assert expected in capsys.readouterr().err


DEVICE_COMMANDS = [
    ["rollout"],
    ["encode-prompt"],
    ["eval", "benchmark", "run"],
    ["eval", "benchmark", "table"],
    ["eval", "video"],
    ["render"],
    ["data", "dedup", "r"],
]


@pytest.mark.parametrize("command", DEVICE_COMMANDS, ids=" ".join)
@pytest.mark.parametrize(
    "value, expected",
    [
        ("gpu0", "expected a torch device such as cpu, cuda or cuda:1, found 'gpu0'"),
        ("cuda", "no CUDA device is available here"),
        ("cuda:7", "no CUDA device is available here"),
        ("meta", "expected cpu, cuda[:N] or mps, found 'meta'"),
    ],
)
def test_a_device_this_machine_lacks_is_refused_by_the_parser(capsys, command, value, expected):
    """--device cuda without CUDA used to fail inside safetensors' loader, after the output folder existed."""
    import torch

    from oscar_core.cli import build_parser

    if value.startswith("cuda") and torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    with pytest.raises(SystemExit) as exit_:
        build_parser().parse_args([*command, "--device", value])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert "argument --device: expected" in err and expected in err


def test_eval_run_checks_the_device_here_only_for_local_rollouts(tmp_path, capsys):
    """--engine ray's workers may be other machines (a GPU cluster driven from a laptop): there --device is only
    parsed; with the local engine a device this machine lacks is refused before the run folder exists."""
    import torch

    from oscar_core.cli import build_parser, main

    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    base = ["eval", "run", str(tmp_path / "m.json"), "--model", "m", "--out", str(tmp_path / "out")]
    assert build_parser().parse_args([*base, "--device", "cuda", "--engine", "ray"]).device == "cuda"
    with pytest.raises(SystemExit):
        build_parser().parse_args([*base, "--device", "gpu0", "--engine", "ray"])
    assert "expected a torch device such as cpu, cuda or cuda:1, found 'gpu0'" in capsys.readouterr().err
    assert main([*base, "--device", "cuda:1"]) == 2
    err = capsys.readouterr().err
    assert "--device: field 'device': expected a device this machine has (with --engine local)" in err
    assert "no CUDA device is available here" in err and not (tmp_path / "out").exists()


def test_an_available_device_is_accepted_and_model_commands_default_to_cuda_when_present(monkeypatch):
    import torch

    from oscar_core._util.arg_types import default_device
    from oscar_core.cli import build_parser

    args = build_parser().parse_args(["eval", "run", "m.json", "--model", "m", "--out", "o", "--device", "cpu"])
    assert args.device == "cpu"
    assert build_parser().parse_args(["eval", "run", "m.json", "--model", "m", "--out", "o"]).device is None  # at run
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    assert default_device() == "cuda"
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    assert default_device() == "cpu"


# ------------------------------------------------------------------ sizes bounded by memory


def test_an_array_larger_than_memory_is_refused_with_its_size():
    from oscar_core._util.memory import ArraySizeError, check_fits

    check_fits((16, 100, 100, 3), 1, "frames", "use a smaller --size", available=16 * 100 * 100 * 3)
    with pytest.raises(ArraySizeError) as err:
        check_fits(
            (16, 100000, 100000, 3),
            1,
            "the skeleton video (T, H, W, 3) uint8",
            "use a smaller --size",
            available=8 * 1024**3,
        )
    assert str(err.value) == (
        "the skeleton video (T, H, W, 3) uint8 of shape (16, 100000, 100000, 3) needs 447.0 GiB, "
        "found 8.0 GiB of memory available; use a smaller --size"
    )


def test_render_of_a_huge_size_is_an_error_not_a_traceback(tmp_path, capsys, monkeypatch):
    from oscar_core._util import memory as _memory
    from oscar_core.cli import main

    monkeypatch.setattr(_memory, "available_bytes", lambda: 2 * 1024**3)  # whatever this machine has
    rc = main(
        [
            "render",
            "--embodiment",
            "toyarm",
            "--trajectory",
            str(TRAJ),
            "--camera",
            str(CAM),
            "--out",
            str(tmp_path / "big.mkv"),
            "--size",
            "20000x20000",
        ]
    )  # one frame fits, a chunk does not
    err = capsys.readouterr().err
    assert rc == 2 and err.startswith("error: the skeleton video (T, H, W, 3) uint8 of shape (")  # T: a chunk
    assert ", 20000, 20000, 3) needs " in err and len(err.splitlines()) == 1
    assert "found 2.0 GiB of memory available; use a smaller --size" in err
    assert not (tmp_path / "big.mkv").exists()


def test_available_memory_is_read_from_the_system():
    from oscar_core._util.memory import available_bytes

    got = available_bytes()
    if sys.platform.startswith("linux"):
        assert got is not None and 0 < got < 1 << 50
    assert got is None or isinstance(got, int)


# ------------------------------------------------------------------ toyworld eval over different clip sets


@pytest.fixture(scope="module")
def toy_preds(tmp_path_factory):
    from oscar_core.plugin.registry import default_registry
    from oscar_core.toyworld.generate import GenerateConfig, generate_clipset
    from oscar_core.train.clips import ClipSet

    root = tmp_path_factory.mktemp("toy")
    generate_clipset(
        GenerateConfig(("kuka",), episodes=3, width=32, height=32, frames=5, seed=1), root / "clips", default_registry()
    )
    clips = ClipSet(root / "clips")
    a, b = root / "a", root / "b"
    a.mkdir(), b.mkdir()
    for k, r in enumerate(clips):
        rgb = clips.load(r, skeleton=False).rgb
        np.save(a / f"{r.id}.npy", rgb)
        if k:  # b lacks the first clip
            np.save(b / f"{r.id}.npy", np.roll(rgb, 2, axis=2))
    return clips, a, b


def test_toyworld_eval_refuses_rows_over_different_clips(toy_preds, capsys):
    from oscar_core.cli import main
    from oscar_core.toyworld.evaluate import evaluate_conditions

    clips, a, b = toy_preds
    first = clips.records[0].id
    with pytest.raises(ValueError) as err:
        evaluate_conditions(clips, {"a": str(a), "b": str(b)})
    assert f"--pred b has 2 clips against 3 of --pred a, lacking {first}" in str(err.value)
    assert "--clips common" in str(err.value)
    rc = main(["toyworld", "eval", "--gt", str(clips.root), "--pred", f"a={a}", "--pred", f"b={b}"])
    assert rc == 2 and "different clips" in capsys.readouterr().err


def test_toyworld_eval_common_clips_or_marked_rows(toy_preds):
    from oscar_core.toyworld.evaluate import evaluate_conditions, format_table

    clips, a, b = toy_preds
    common = evaluate_conditions(clips, {"a": str(a), "b": str(b)}, clips_mode="common")
    assert common["same_clips"] is True
    assert common["rows"]["a"]["clips"] == common["rows"]["b"]["clips"] == 2
    assert set(common["clips"]["a"]) == set(common["clips"]["b"])
    assert "not comparable" not in format_table(common)
    each = evaluate_conditions(clips, {"a": str(a), "b": str(b)}, clips_mode="each")
    assert each["same_clips"] is False and (each["rows"]["a"]["clips"], each["rows"]["b"]["clips"]) == (3, 2)
    assert "not comparable: the rows are means over different clips" in format_table(each)
    same = evaluate_conditions(clips, {"a": str(a), "a2": str(a)})  # identical clip sets: nothing to refuse
    assert same["same_clips"] is True and not math.isnan(same["rows"]["a2"]["psnr_db"])


def test_rollout_and_export_refuse_a_size_beyond_memory_before_work(capsys, monkeypatch, tmp_path):
    from oscar_core._util import memory as _memory
    from oscar_core.data.run import run_export, run_ingest

    monkeypatch.setattr(_memory, "available_bytes", lambda: 1024**3)
    msg = _rollout(capsys, monkeypatch, tmp_path, tmp_path / "v.mp4", "--size", "4096x4096")
    assert msg.startswith("the skeleton video (T, H, W, 3) uint8 at --size of shape (81, 4096, 4096, 3) needs 3.8 GiB")

    from _datasets import write_episode

    write_episode(tmp_path / "src", "ep0")
    run_ingest(str(tmp_path / "src"), "npz", str(tmp_path / "run"), workers=1, progress=False)
    with pytest.raises(
        OscarError,
        match=r"the longest live episode at --size \(T, H, W, 3\) uint8 of shape "
        r"\(\d+, 8192, 8192, 3\) needs .* GiB, found 1.0 GiB",
    ):
        run_export(str(tmp_path / "run"), str(tmp_path / "clips"), size=(8192, 8192), workers=1, progress=False)
    assert not (tmp_path / "clips").exists() and not (tmp_path / "run" / "export").exists()


@pytest.mark.parametrize(
    "item, expected",
    [
        ("min_length=nan", "--set min_length: expected a number (int), found 'nan'"),
        ("max_camera_motion=nan", "--set max_camera_motion: expected a finite number >= 0 (float), found 'nan'"),
        ("min_action=-0.1", "--set min_action: expected a finite number >= 0 (float), found '-0.1'"),
        ("motion_pairs=0", "--set motion_pairs: expected a finite number >= 1 (int), found '0'"),
        ("min_length=7.5", "--set min_length: expected a number (int), found '7.5'"),
    ],
)
def test_filter_thresholds_are_checked(item, expected):
    from oscar_core.data.filters import FilterConfig

    with pytest.raises(ValueError) as err:
        FilterConfig.from_overrides([item])
    assert str(err.value) == expected
    assert FilterConfig.from_overrides(["min_length=0", "min_visible=0.5"]).min_visible == 0.5


def test_a_size_whose_one_frame_exceeds_memory_is_refused_by_every_command(monkeypatch, capsys):
    from oscar_core._util import memory as _memory
    from oscar_core.cli import main
    from oscar_core.render.skeleton_video import parse_size

    monkeypatch.setattr(_memory, "available_bytes", lambda: 1024**3)
    assert parse_size("512x288") == (512, 288)
    with pytest.raises(
        OscarError,
        match=r"--size 20000x20000: one RGB frame of shape \(20000, 20000, 3\) needs "
        r"1.1 GiB, found 1.0 GiB of memory available; use a smaller --size",
    ):
        parse_size("20000x20000")
    assert (
        main(
            [
                "toyworld",
                "generate",
                "--embodiments",
                "kuka",
                "--episodes",
                "1",
                "--size",
                "20000x20000",
                "--out",
                "unused",
            ]
        )
        == 2
    )
    assert capsys.readouterr().err.startswith("error: --size 20000x20000: one RGB frame")


def test_an_allocation_failure_is_one_line(monkeypatch, capsys):
    import oscar_core.cli as cli

    def boom(args):
        raise MemoryError("Unable to allocate 596. GiB for an array with shape (2, 200000, 200000) and data type int64")

    monkeypatch.setattr(cli, "cmd_embodiments", boom)
    assert cli.main(["embodiments"]) == 2
    err = capsys.readouterr().err
    assert err == (
        "error: out of memory: Unable to allocate 596. GiB for an array with shape (2, 200000, 200000) and "
        "data type int64; a smaller --size, fewer frames or fewer workers need less\n"
    )


@pytest.mark.parametrize("device", ["cuda", "cuda:3", "gpu", "meta"])
def test_the_python_api_refuses_a_device_this_machine_lacks_before_reading_weights(device, monkeypatch, tmp_path):
    """oscar_zoo.load and OscarWorldModel.from_pretrained name the device; no download is attempted."""
    import torch

    import oscar_zoo
    from oscar_core.model.world_model import OscarWorldModel

    if device.startswith("cuda") and torch.cuda.is_available():
        pytest.skip("this machine has CUDA")

    def no_fetch(*a, **k):
        raise AssertionError("fetched before the device was checked")

    monkeypatch.setattr("oscar_zoo._load.fetch", no_fetch)
    with pytest.raises(ModelInputError, match=f"device: expected .*found '{device}'"):
        oscar_zoo.load("oscar-toy", device=device)
    with pytest.raises(ModelInputError, match=f"device: expected .*found '{device}'"):
        OscarWorldModel.from_pretrained(tmp_path / "missing", device=device)
