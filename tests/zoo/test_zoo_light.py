"""``oscar zoo list`` and ``oscar zoo pull`` need no torch: the table and the hash check are plain Python."""

from __future__ import annotations

import json
import os
import subprocess
import sys

HEAVY = ("torch", "diffusers", "transformers", "matplotlib")

PROBE = """
import json, sys
from oscar_core.cli import main
code = main(sys.argv[1:])
print(json.dumps({"code": code, "heavy": sorted(m for m in HEAVY if m in sys.modules)}))
""".replace("HEAVY", repr(HEAVY))


def _run(*argv):
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "OMP_NUM_THREADS": "1"}
    out = subprocess.run([sys.executable, "-c", PROBE, *argv], capture_output=True, text=True, env=env, timeout=120)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_zoo_list_imports_no_torch():
    assert _run("zoo", "list") == {"code": 0, "heavy": []}


def test_zoo_pull_of_the_bundled_model_imports_no_torch():
    assert _run("zoo", "pull", "oscar-toy") == {"code": 0, "heavy": []}


def test_the_model_file_names_are_the_world_models():
    from oscar_core.model import _files, world_model

    assert (world_model.MODEL_FILE, world_model.EMPTY_PROMPT_FILE, world_model.SCHEDULER_FILE) == (
        _files.MODEL_FILE,
        _files.EMPTY_PROMPT_FILE,
        _files.SCHEDULER_FILE,
    )
