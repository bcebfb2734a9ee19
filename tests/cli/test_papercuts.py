"""Small things a newcomer trips on: a one-file plugin with its URDF as text, a sub-command's own examples in its
--help, labels on every contact-sheet row, and read-only NumPy frames through the rollout API without a warning."""

import argparse
import textwrap
import warnings

import numpy as np
import pytest
from _models import tiny_world_model
from _paths import REPO

from oscar_core.errors import KinematicsFileError, PluginError
from oscar_core.plugin.registry import Registry

TOYARM_URDF = REPO / "examples" / "oscar-toyarm" / "oscar_toyarm" / "assets" / "toyarm.urdf"

PLUGIN = """
from oscar_core import Embodiment, Gripper, Skeleton, hookimpl

URDF = {urdf!r}


class TextArm(Embodiment):
    name = "textarm"
    license = "Apache-2.0"
    urdf_text = URDF{extra}
    skeleton = Skeleton(links=("base_link", "turntable", "upper_arm", "forearm", "wrist", "tool", "left_finger",
                               "right_finger"),
                        points={{"left_finger": (0.0, 0.0, 0.03), "right_finger": (0.0, 0.0, 0.03)}})
    grippers = (Gripper("gripper", link="tool", signal_range=(0.0, 0.08), closed_at="low", joint="finger_left",
                        joint_range=(0.0, 0.04)),)


@hookimpl
def oscar_register_embodiments():
    return [TextArm]
"""


def _plugin(tmp_path, urdf: str, extra: str = "") -> Registry:
    path = tmp_path / "textarm.py"
    path.write_text(PLUGIN.format(urdf=urdf, extra=extra))
    return Registry(plugin_paths=[path])


def test_a_one_file_plugin_gives_its_urdf_as_text_and_moves_like_the_file(tmp_path):
    reg = _plugin(tmp_path, TOYARM_URDF.read_text())
    text, toy = reg.get("textarm"), reg.get("toyarm")
    assert text.joint_names == toy.joint_names
    q = np.random.default_rng(0).uniform(-1.0, 1.0, (6, len(toy.joint_names)))
    from oscar_core.kinematics.workspace import open_fk

    for got, want in zip(open_fk(text, q), open_fk(toy, q)):  # skeleton points and end-effector, metres
        np.testing.assert_allclose(got, want, atol=1e-12)


def test_a_broken_urdf_text_is_named_by_its_plugin(tmp_path):
    bad = TOYARM_URDF.read_text().replace('type="revolute"', 'type="screw"', 1)
    reg = _plugin(tmp_path, bad)
    with pytest.raises(
        (KinematicsFileError, PluginError),
        match=r"<urdf_text of embodiment 'textarm' "
        r"\(.*TextArm\)>: field 'joint\[.*\]\.type'",
    ):
        reg.get("textarm")
    reg = _plugin(tmp_path, "<robot name='x'><link name='a'/>")
    with pytest.raises((KinematicsFileError, PluginError), match=r"<urdf_text of embodiment 'textarm'.*well-formed"):
        reg.get("textarm")


def test_urdf_and_urdf_text_together_break_the_contract(tmp_path):
    reg = _plugin(tmp_path, TOYARM_URDF.read_text(), extra=f"\n    urdf = {str(TOYARM_URDF)!r}")
    assert "textarm" not in reg.names()
    assert any("expected exactly one kinematic description, found urdf and urdf_text" in f.error for f in reg.failures)


# ------------------------------------------------------------------ --help: a sub-command's own examples


def _leaves(parser):
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        yield parser
        return
    for action in subs:
        for child in {id(c): c for c in action.choices.values()}.values():
            yield from _leaves(child)


def test_every_sub_commands_help_shows_only_its_own_examples():
    from oscar_core._util.cli_examples import example_command
    from oscar_core.cli import build_parser

    checked = 0
    for leaf in _leaves(build_parser()):
        commands = [
            example_command(line)
            for line in (leaf.epilog or "").splitlines()
            if line.startswith("  ") and not line.startswith("    ")
        ]
        commands = [c for c in commands if c]
        for c in commands:
            assert c == leaf.prog or c.startswith(leaf.prog + " "), (leaf.prog, c)
        checked += bool(commands)
    assert checked >= 30  # most sub-commands show at least one example


def test_toyworld_generate_help_keeps_its_examples_with_their_continuation_lines(capsys):
    from oscar_core.cli import main

    with pytest.raises(SystemExit):
        main(["toyworld", "generate", "--help"])
    out = capsys.readouterr().out
    assert out.count("  oscar toyworld generate --embodiments") == 3  # robots, misses, human hands
    assert "--seed 0 --out clipsets/toyworld\n" in out and "miss the ball" in out and "(human hands:" in out
    assert "oscar toyworld eval" not in out and "oscar toyworld train-vae" not in out
    with pytest.raises(SystemExit):
        main(["toyworld", "--help"])  # the group still lists them all
    out = capsys.readouterr().out
    assert "oscar toyworld eval" in out and "oscar toyworld generate" in out


def test_filter_examples_keeps_text_around_the_block():
    from oscar_core._util.cli_examples import filter_examples

    epilog = textwrap.dedent("""\
        examples:
          oscar g a --x 1 \\
              --y 2   (note)
          HF_HUB_OFFLINE=1 oscar --plugin p.py g b --z
          oscar g a ... --w
          torchrun -m oscar_core.train cfg.yaml

        A closing sentence.
        """)
    assert filter_examples(epilog, "oscar g a") == textwrap.dedent("""\
        examples:
          oscar g a --x 1 \\
              --y 2   (note)
          oscar g a ... --w
          torchrun -m oscar_core.train cfg.yaml

        A closing sentence.
        """)
    assert "oscar --plugin p.py g b --z" in filter_examples(epilog, "oscar g b")
    assert filter_examples(epilog, "oscar other") == epilog  # no entry of its own: left whole


# ------------------------------------------------------------------ read-only frames


def test_a_read_only_frame_goes_through_the_rollout_api_without_a_warning():
    import torch

    from oscar_core.model import SamplerConfig
    from oscar_core.model.vae import VideoVAE

    rng = np.random.default_rng(0)
    first = rng.integers(0, 256, (16, 32, 3), dtype=np.uint8)
    skel = rng.integers(0, 256, (5, 16, 32, 3), dtype=np.uint8)
    ro_first, ro_skel = first.copy(), skel.copy()
    ro_first.flags.writeable = ro_skel.flags.writeable = False
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        px = VideoVAE.to_pixels(np.broadcast_to(first, (5, 16, 32, 3)))  # a read-only view
    assert px.shape == (1, 3, 5, 16, 32) and float(px[0, :, 0].max()) <= 1.0
    model = tiny_world_model(name="tiny", chunk_frames=5, fps=10.0, empty_prompt=torch.zeros(1, 1, 48))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        a = model.rollout(ro_first, ro_skel, sampler=SamplerConfig(steps=1), progress=False).frames
    assert [str(w.message) for w in caught if "writable" in str(w.message)] == []
    b = model.rollout(first, skel, sampler=SamplerConfig(steps=1), progress=False).frames
    np.testing.assert_array_equal(a, b)


# ------------------------------------------------------------------ the demo's contact sheet


def test_a_short_row_is_labelled_beside_its_frames_and_its_panels_named_under_them():
    """The toy world's row (rollout | ground truth | skeleton, shorter than the skeleton rows) gets its name centred
    on its own frames and a caption under each panel, like every row's name: on the sheet, never in a frame."""
    from oscar_core.demo import TOY_PANELS, contact_sheet

    tall = np.zeros((3, 60, 90, 3), np.uint8)
    short = np.full((3, 20, 90, 3), 120, np.uint8)
    sheet = contact_sheet([tall, short], columns=2, labels=["franka", "oscar-toy"], panels=[None, TOY_PANELS])
    plain = contact_sheet([tall, short], columns=2, labels=["franka", "oscar-toy"])
    band = sheet.shape[1] - 2 * (90 + 4) - 4
    H = (sheet.shape[0] - 4) // 2 - 4  # the grid height (frames + captions of the short row fit in it)
    y = 4 + H + 4  # the short row's top
    text = (sheet[y : y + H, :band] > 100).any(-1)
    rows = np.flatnonzero(text.any(1))
    assert rows.size and rows.max() < 20  # the name sits beside the 20 frame rows, not lower
    for j in range(2):  # frames untouched, captions below them in each column
        x = band + 4 + j * (90 + 4)
        np.testing.assert_array_equal(sheet[y : y + 20, x : x + 90], short[0])
        below = (sheet[y + 20 : y + H, x : x + 90] > 100).any(-1)
        cols = np.flatnonzero(below.any(0))
        assert cols.size and cols.min() < 30 and cols.max() > 60  # under the first and the last panel
        assert (plain[y + 20 : y + H, x : x + 90] > 100).sum() == 0  # nothing there without panels
    with pytest.raises(ValueError, match="expected 2 panel lists"):
        contact_sheet([tall, short], panels=[None])


def _groups(parser):
    for action in [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]:
        yield parser, action
        for child in {id(c): c for c in action.choices.values()}.values():
            yield from _groups(child)


def _matches_prog(command: str, prog: str) -> bool:
    return command == prog or command.startswith(prog + " ")


def test_oscar_eval_help_has_one_examples_block_with_every_sub_command():
    """``oscar eval --help``: one examples block (not one per sub-command stacked) with an example of each of its
    sub-commands, closed-loop included; every other group with examples has at most one block too."""
    from oscar_core._util.cli_examples import example_command
    from oscar_core.cli import build_parser

    seen = False
    for group, action in _groups(build_parser()):
        epilog = group.epilog or ""
        assert epilog.count("examples:") <= 1, (group.prog, epilog.count("examples:"))
        if group.prog == "oscar eval":
            seen = True
            shown = [c for c in map(example_command, epilog.splitlines()) if c]
            missing = [n for n in action.choices if not any(_matches_prog(c, f"oscar eval {n}") for c in shown)]
            assert not missing, missing
    assert seen


@pytest.mark.parametrize("command", [["eval", "run"], ["eval", "closed-loop"], ["eval", "benchmark", "run"]])
def test_eval_steps_default_is_the_model_cards_and_the_help_says_so(command):
    """No --steps: the card's steps (oscar-toy's card recommends 20), and --steps' help names the card as the
    default (it said 35, the library's fallback)."""
    from oscar_core.cli import build_parser
    from oscar_core.evaluation.cli_options import resolve_sampler_flags

    parser = build_parser()
    leaf = parser
    for word in command:
        leaf = next(a for a in leaf._actions if isinstance(a, argparse._SubParsersAction)).choices[word]
    steps = next(a for a in leaf._actions if "--steps" in a.option_strings)
    assert "the model card's" in steps.help and "default 35" not in steps.help
    args = argparse.Namespace(**{a.dest: a.default for a in leaf._actions if a.dest != "help"})
    assert resolve_sampler_flags(args, lambda: {"steps": 20}).config.steps == 20
    assert resolve_sampler_flags(args, lambda: None).config.steps == 35
