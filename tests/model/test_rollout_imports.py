"""What a toy rollout imports: oscar's own modules add nothing to what torch and diffusers' two model classes import.

``oscar rollout`` of ``oscar-toy`` imports the command module, ``rollout_files`` and ``world_model`` before it reads
weights. Nearly all of that cost is torch and diffusers (``torch._dynamo``, transformers and scipy come with
diffusers' ``CosmosTransformer3DModel`` and ``AutoencoderKLWan``; benchmarks/startup.py measures both). This test
keeps oscar's share at its own modules: any third-party module, or diffusers module, that oscar's rollout path
brings in beyond those two classes (a plotting library, a video reader, a diffusers pipeline at import time) fails
it, with the modules named. Run in a fresh interpreter; no timing."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

#: the floor: torch and the two diffusers classes the world model is built from, imported as diffusers' own modules
FLOOR = (
    "import torch\n"
    "from diffusers.models.transformers.transformer_cosmos import CosmosTransformer3DModel\n"
    "from diffusers.models.autoencoders.autoencoder_kl_wan import AutoencoderKLWan\n"
)
#: what ``oscar rollout`` imports before it reads weights (the same as benchmarks/startup.py's toy row)
TOY_ROLLOUT = (
    "import oscar_core.cli, oscar_core.model.cli, oscar_core.model.rollout_files\n"
    "from oscar_core.model.world_model import OscarWorldModel\n"
)
OWN = {"oscar_core", "oscar_zoo", "oscar_embodiments"}


def added_by(floor: str, code: str) -> list[str]:
    """The modules a fresh interpreter holds after running ``floor`` then ``code`` and not after ``floor`` alone."""
    script = (
        "import json, sys\n"
        f"{floor}"
        "before = set(sys.modules)\n"
        f"{code}"
        "print(json.dumps(sorted(set(sys.modules) - before)), file=sys.stderr)\n"
    )
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stderr.strip().splitlines()[-1])


def not_own(modules: list[str]) -> list[str]:
    """``modules`` less oscar's own and the standard library's."""
    return [m for m in modules if m.split(".")[0] not in OWN | set(sys.stdlib_module_names)]


@pytest.mark.slow
def test_the_toy_rollout_path_adds_only_oscars_own_modules_to_torch_and_diffusers_classes():
    added = added_by(FLOOR, TOY_ROLLOUT)
    assert "oscar_core.model.world_model" in added  # the probe ran
    extra = not_own(added)
    packages = sorted({m.split(".")[0] for m in extra})
    assert extra == [], f"the toy rollout path imports {packages} beyond torch and diffusers' DiT and VAE: {extra[:12]}"


def test_the_probe_names_third_party_modules_only():
    extra = not_own(added_by("import json\n", "import email.mime.text, oscar_core.errors, numpy\n"))
    assert "numpy" in extra and {m.split(".")[0] for m in extra} == {"numpy"}
