"""What a toy rollout imports: no diffusers, no transformers, no torch._dynamo, and beyond torch only oscar's modules.

``oscar rollout`` of the bundled ``oscar-toy`` runs on oscar's own DiT (model/cosmos_dit.py), Wan VAE
(model/wan_vae.py) and UniPC solver (model/unipc.py), so none of the three heavy imports that used to make up most
of its start-up (diffusers imports ``torch._dynamo`` from ``diffusers.utils`` and transformers with its model base
classes; benchmarks/startup.py measures them) is needed. The first test runs the whole command, one chunk of the
toyarm example at one step, in a fresh interpreter and fails naming any of them it finds loaded at the end; the
second keeps what the command imports before reading weights to torch and oscar's own modules, so a new third-party
import on that path (a plotting library, a video reader at import time) is a decision someone takes, with the
modules named. No timing (benchmarks/startup.py measures the seconds)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from _paths import TOYARM_ASSETS

#: packages a toy rollout must not import (a dotted name covers its submodules)
HEAVY = ("diffusers", "transformers", "torch._dynamo")
#: what ``oscar rollout`` imports before it reads weights (the same as benchmarks/startup.py's toy row)
TOY_ROLLOUT = (
    "import oscar_core.cli, oscar_core.model.cli, oscar_core.model.rollout_files\n"
    "from oscar_core.model.world_model import OscarWorldModel\n"
)
#: third-party packages the toy path may import beside torch's own: the weights' reader
ALLOWED = {"safetensors"}
OWN = {"oscar_core", "oscar_zoo", "oscar_embodiments"}


def heavy_in(modules) -> list[str]:
    """The :data:`HEAVY` packages ``modules`` (names as in ``sys.modules``) hold, sorted."""
    return sorted({h for h in HEAVY for m in modules if m == h or m.startswith(h + ".")})


def run_python(code: str) -> str:
    """The last line ``code`` prints on stderr in a fresh interpreter (asserting it exits 0)."""
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stderr.strip().splitlines()[-1]


@pytest.fixture(scope="module")
def toy_inputs(tmp_path_factory) -> dict[str, str]:
    """A first frame (PNG, the camera's 640x360) and the toyarm example's first 17 frames at 10 fps (one oscar-toy
    chunk at its frame rate, so nothing is resampled) with its camera."""
    import cv2
    import numpy as np

    from oscar_core.kinematics.trajectory import load_trajectory, save_trajectory

    folder = tmp_path_factory.mktemp("toy-rollout")
    first = folder / "first.png"
    cv2.imwrite(str(first), np.random.default_rng(0).integers(0, 256, (360, 640, 3), dtype=np.uint8))
    trajectory = load_trajectory(TOYARM_ASSETS / "example_trajectory.npz").time_slice(0, 17).replace(fps=10.0)
    return {
        "first": str(first),
        "trajectory": str(save_trajectory(trajectory, folder / "trajectory.npz")),
        "camera": str(TOYARM_ASSETS / "example_camera.json"),
        "out": str(folder / "rollout.mp4"),
    }


@pytest.mark.slow
def test_a_toy_rollout_imports_no_diffusers_transformers_or_dynamo(toy_inputs):
    argv = [
        "rollout", "--model", "oscar-toy", "--embodiment", "toyarm", "--first-frame", toy_inputs["first"],
        "--trajectory", toy_inputs["trajectory"], "--camera", toy_inputs["camera"], "--out", toy_inputs["out"],
        "--steps", "1", "--no-progress", "--no-side-by-side",
    ]  # fmt: skip
    code = (
        "import json, sys\n"
        "from oscar_core.cli import main\n"
        f"code = main({argv!r})\n"
        "print(json.dumps([code, sorted(sys.modules)]), file=sys.stderr)\n"
    )
    exit_code, modules = json.loads(run_python(code))
    assert exit_code == 0 and Path(toy_inputs["out"]).is_file()  # the rollout ran
    assert "oscar_core.model.unipc" in modules and "oscar_core.model.wan_vae" in modules
    heavy = heavy_in(modules)
    examples = [m for m in modules if heavy_in([m])][:8]
    assert heavy == [], f"a toy rollout imports {heavy} (e.g. {examples})"


def added_by(floor: str, code: str) -> list[str]:
    """The modules a fresh interpreter holds after running ``floor`` then ``code`` and not after ``floor`` alone."""
    script = (
        "import json, sys\n"
        f"{floor}"
        "before = set(sys.modules)\n"
        f"{code}"
        "print(json.dumps(sorted(set(sys.modules) - before)), file=sys.stderr)\n"
    )
    return json.loads(run_python(script))


def not_own(modules: list[str]) -> list[str]:
    """``modules`` less oscar's own, the standard library's and the :data:`ALLOWED` packages'."""
    skip = OWN | ALLOWED | set(sys.stdlib_module_names)
    return [m for m in modules if m.split(".")[0] not in skip]


@pytest.mark.slow
def test_the_toy_rollout_imports_add_only_oscars_own_modules_to_torch():
    added = added_by("import torch\n", TOY_ROLLOUT)
    assert "oscar_core.model.world_model" in added  # the probe ran
    extra = not_own(added)
    packages = sorted({m.split(".")[0] for m in extra})
    assert extra == [], f"the toy rollout path imports {packages} beyond torch: {extra[:12]}"


def test_the_probes_name_third_party_and_heavy_modules_only():
    extra = not_own(added_by("import json\n", "import email.mime.text, oscar_core.errors, numpy\n"))
    assert "numpy" in extra and {m.split(".")[0] for m in extra} == {"numpy"}
    assert heavy_in(["torch", "torch._dynamo.utils", "diffusers", "transformersx", "oscar_core"]) == [
        "diffusers",
        "torch._dynamo",
    ]
