"""``oscar train --export RUN --sampler JSON``: the exported card recommends the sampler given (what every entry point
then samples with unless told otherwise); a bad mapping, and any for a distilled student, is refused by flag and key
before anything is written (exit 2)."""

import re

import pytest
import yaml
from _models import tiny_clipset, tiny_train_config

from oscar_core.cli import main
from oscar_core.model.errors import ModelInputError
from oscar_core.train.export import export_run
from oscar_core.train.loop import train

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("export_sampler")
    config = tiny_train_config(tiny_clipset(tmp / "clips", clips=2), tmp / "run", steps=1, save_every=1)
    train(config, progress=False)
    return tmp / "run"


def test_the_card_recommends_the_sampler_given(run, tmp_path):
    import oscar_zoo

    args = ["train", "--export", str(run), "--out", str(tmp_path / "m"), "--sampler", '{"steps": 10, "guidance": 0}']
    assert main(args) == 0
    model = oscar_zoo.load(tmp_path / "m")
    assert model.card.sampler == {"steps": 10, "guidance": 0}
    chosen = model.recommended_sampler()
    assert (chosen.steps, chosen.guidance) == (10, 0)
    assert model.recommended_sampler(steps=4).steps == 4  # a flag still wins
    # without the option the card recommends nothing, and rollouts take the library's settings
    plain = oscar_zoo.load(export_run(run, tmp_path / "plain"))
    assert plain.card.sampler is None and plain.recommended_sampler().steps == 35


@pytest.mark.parametrize(
    "text, expected",
    [
        ("steps=10", "--sampler: expected a JSON mapping"),
        ("[10, 0]", "--sampler: expected a mapping"),
        ('{"step": 10}', r"--sampler: expected keys among steps, guidance, guidance_form, preset, found \['step'\]"),
        ('{"steps": 0}', r"--sampler\.steps: expected an integer >= 1, found 0"),
        ('{"guidance": -1}', r"--sampler\.guidance: expected a finite number >= 0"),
        ('{"guidance_form": "cfg"}', r"--sampler\.guidance_form: expected one of"),
    ],
)
def test_a_bad_sampler_is_refused_by_flag_and_key_before_anything_is_written(run, tmp_path, capsys, text, expected):
    out = tmp_path / "m"
    assert main(["train", "--export", str(run), "--out", str(out), "--sampler", text]) == 2
    assert re.search(expected, capsys.readouterr().err)
    assert not out.exists() and not list(tmp_path.glob(".m.*"))


def test_a_distilled_students_sampler_is_its_own(run, tmp_path):
    config = yaml.safe_load((run / "config.yaml").read_text())
    config["distill"]["teacher"] = config["model"]["init"] = str(tmp_path)
    student = tmp_path / "student"
    student.mkdir()
    (student / "config.yaml").write_text(yaml.safe_dump(config))
    with pytest.raises(ModelInputError, match=r"student: export sampler: expected none for a distilled student"):
        export_run(student, tmp_path / "m", sampler={"steps": 8})
    assert not (tmp_path / "m").exists()


def _config_file(tmp_path, clips, run_dir, **over) -> str:
    """A YAML config of the tiny run (1 step) with ``over`` set, as a user writes one."""
    from oscar_core.train.config import config_to_dict

    d = config_to_dict(tiny_train_config(clips, run_dir, steps=1, save_every=1))
    for key, value in over.items():
        *parents, last = key.split(".")
        node = d
        for p in parents:
            node = node[p]
        node[last] = value
    path = tmp_path / "config.yaml"
    path.write_text(yaml.safe_dump(d))
    return str(path)


def test_the_runs_export_sampler_goes_into_the_end_of_run_export_and_a_flag_wins(tmp_path):
    import oscar_zoo

    clips = tiny_clipset(tmp_path / "clips", clips=2)
    wanted = {"steps": 10, "guidance": 0.0, "guidance_form": "diffusers"}
    config = _config_file(tmp_path, clips, tmp_path / "run", export=True, export_sampler=wanted)
    assert main(["train", config, "--no-progress"]) == 0
    auto = oscar_zoo.load(tmp_path / "run" / "export")  # the export the run wrote at its end
    assert auto.card.sampler == wanted
    assert (auto.recommended_sampler().steps, auto.recommended_sampler().guidance) == (10, 0.0)
    again = oscar_zoo.load(export_run(tmp_path / "run", tmp_path / "again"))  # --export without --sampler
    assert again.card.sampler == wanted
    flagged = tmp_path / "flagged"
    assert main(["train", "--export", str(tmp_path / "run"), "--out", str(flagged), "--sampler", '{"steps": 4}']) == 0
    assert oscar_zoo.load(flagged).card.sampler == {"steps": 4}


def test_export_sampler_can_be_set_when_a_run_is_trained_further(tmp_path):
    import oscar_zoo

    clips = tiny_clipset(tmp_path / "clips", clips=2)
    config = _config_file(tmp_path, clips, tmp_path / "run")
    assert main(["train", config, "--no-progress"]) == 0
    args = ["train", "--resume", str(tmp_path / "run"), "--no-progress", "--set", "steps=2"]
    assert main([*args, "--set", "export_sampler={steps: 12, guidance: 1.5}"]) == 0
    assert yaml.safe_load((tmp_path / "run" / "config.yaml").read_text())["export_sampler"] == {
        "steps": 12,
        "guidance": 1.5,
    }
    assert oscar_zoo.load(export_run(tmp_path / "run", tmp_path / "m")).card.sampler == {"steps": 12, "guidance": 1.5}


@pytest.mark.parametrize(
    "value, expected",
    [
        ([10, 0], r"field 'export_sampler': expected a mapping, found list"),
        ({"step": 10}, r"export_sampler: expected keys among steps, guidance, guidance_form, preset, found \['step'\]"),
        ({"steps": 0}, r"export_sampler\.steps: expected an integer >= 1, found 0"),
        ({"guidance": float("nan")}, r"export_sampler\.guidance: expected a finite number >= 0"),
        ({"guidance_form": "cfg"}, r"export_sampler\.guidance_form: expected one of"),
        ({"preset": "fastest"}, r"export_sampler\.preset: expected one of"),
    ],
)
def test_a_bad_export_sampler_is_refused_by_file_and_field_before_the_run_starts(tmp_path, capsys, value, expected):
    clips = tiny_clipset(tmp_path / "clips", clips=2)
    config = _config_file(tmp_path, clips, tmp_path / "run", export=True, export_sampler=value)
    assert main(["train", config, "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert config in err and re.search(expected, err)
    assert not (tmp_path / "run").exists()


def test_a_distillation_run_refuses_an_export_sampler(tmp_path, capsys):
    clips = tiny_clipset(tmp_path / "clips", clips=2)
    over = {"distill.teacher": str(tmp_path), "model.init": str(tmp_path), "export_sampler": {"steps": 8}}
    config = _config_file(tmp_path, clips, tmp_path / "run", **over)
    assert main(["train", config, "--no-progress"]) == 2
    assert re.search(r"field 'export_sampler': expected null for a distillation run", capsys.readouterr().err)
    assert not (tmp_path / "run").exists()
