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
