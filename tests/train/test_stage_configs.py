"""The real stage 1 -> stage 2 recipe of docs/training.md: both configs load and validate, they chain, and every
command of the documented sequence parses with the real command-line parser."""

import re
import shlex

from _paths import REPO

from oscar_core.cli import build_parser
from oscar_core.train.config import load_config, parse_overrides

HUMAN = {"clipsets/egodex", "clipsets/epic"}


def _section_commands(
    page: str = "training.md", heading: str = "### Stage 1 → stage 2 on real data"
) -> list[list[str]]:
    text = (REPO / "docs" / page).read_text()
    section = text.split(heading, 1)[1]
    block = re.search(r"```bash\n(.*?)```", section, re.S).group(1)
    joined = re.sub(r"\\\n\s*", " ", block)
    return [shlex.split(line) for line in joined.splitlines() if line.strip() and not line.lstrip().startswith("#")]


def test_stage_one_and_two_configs_load_validate_and_chain():
    one = load_config(REPO / "configs" / "train" / "oscar-2b.yaml")
    two = load_config(REPO / "configs" / "train" / "oscar-2b-stage2.yaml")
    assert one.parent_run is None and two.parent_run == one.run_dir
    assert set(one.data.clips).isdisjoint(HUMAN)
    assert set(one.data.clips) < set(two.data.clips) and set(two.data.clips) & HUMAN
    # the same network and data geometry, so stage 2 can load stage 1's weights
    assert (one.model.transformer, one.condition, one.data.window) == (
        two.model.transformer,
        two.condition,
        two.data.window,
    )


def test_the_documented_sequence_parses_and_names_the_configs():
    commands = _section_commands()
    assert [c[:3] for c in commands if c[1] == "train"] == [
        ["oscar", "train", "configs/train/oscar-2b.yaml"],
        ["oscar", "train", "configs/train/oscar-2b-stage2.yaml"],
    ]
    readers = set()
    parser = build_parser()
    for argv in commands:
        assert argv[0] == "oscar"
        args = parser.parse_args(argv[1:])  # argparse exits (a test error) on a wrong sub-command or option
        if argv[1:3] == ["data", "ingest"]:
            readers.add(args.reader)
    assert {"egodex", "epic_vitra"} <= readers
    # the stage-2 --set names every clip set the sequence exports, and they load as a valid config
    exported = {c[c.index("--out") + 1] for c in commands if c[1:3] == ["data", "export"]}
    stage2 = next(c for c in commands if c[1] == "train" and "--set" in c)
    value = stage2[stage2.index("--set") + 1]
    config = load_config(REPO / "configs" / "train" / "oscar-2b-stage2.yaml", {"data.clips": _yaml(value)})
    assert set(config.data.clips) == exported and HUMAN <= exported


def _yaml(item: str):
    import yaml

    key, value = item.split("=", 1)
    assert key == "data.clips"
    return yaml.safe_load(value)


def test_the_toy_robot_and_hand_commands_parse_and_their_overrides_make_a_valid_config():
    commands = _section_commands("toyworld.md", "## Robot and hand clips in one training run")
    parser = build_parser()
    for argv in commands:
        parser.parse_args(argv[1:])
    train = next(c for c in commands if c[1] == "train" and "--set" in c)
    sets = [train[i + 1] for i, a in enumerate(train) if a == "--set"]
    config = load_config(REPO / train[2], parse_overrides(sets))
    assert config.data.source_weights == {"toyworld": 1.0, "toyworld_hand": 1.0}
    assert config.data.clips == ["clipsets/toyworld-latents", "clipsets/toyworld-hands-latents"]
