"""A real install into a fresh virtual environment (no system packages).

Checks what a user gets from ``pip install ".[mano]"``: the wheel carries
every embodiment's assets (the demo renders all of them from the installed
package, not the checkout), the ``mano`` extra pulls smplx and the MANO
parameter path imports; after ``pip uninstall smplx`` the keypoint path
still works and the parameter path names the install command. A plugin
(the packaged example ``examples/oscar-toyarm``, which declares
``oscar-wm>=0.1`` as docs/write-a-plugin.md tells authors to) installs
beside it with dependency resolution on; in a fresh environment without
oscar, installing that plugin fails with pip's message naming ``oscar-wm``
and installs nothing, never the unrelated ``oscar`` of the package index.

Marked ``install``: it downloads oscar's dependencies from the package index
(torch comes from the local wheel pinned in requirements-ci.txt), a few
minutes. ``make test-install`` runs it; CI runs it through ``.ci/run``.
"""

import json
import os
import shutil
import subprocess
import venv
from pathlib import Path

import pytest
from _paths import REPO

import oscar_core

pytestmark = [pytest.mark.install, pytest.mark.slow]


def run(cmd, cwd, timeout=1200, check=True):
    env = {k: v for k, v in os.environ.items() if not k.startswith(("PYTHON", "VIRTUAL_ENV", "OSCAR_"))}
    proc = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=timeout, env=env)
    if not check:
        return proc
    assert proc.returncode == 0, f"{' '.join(map(str, cmd))} failed:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    return proc.stdout


def plugin_copy(tmp_path) -> Path:
    """The packaged example plugin, copied so that building it leaves the checkout untouched."""
    dst = tmp_path / "oscar-toyarm"
    shutil.copytree(REPO / "examples" / "oscar-toyarm", dst, ignore=shutil.ignore_patterns("*.egg-info", "__pycache__"))
    return dst


def installed(py, cwd) -> dict[str, str]:
    rows = json.loads(run([py, "-m", "pip", "list", "--format", "json"], cwd))
    return {r["name"].lower(): r["version"] for r in rows}


def test_fresh_venv_install_with_mano_extra(tmp_path):
    env_dir = tmp_path / "venv"
    venv.EnvBuilder(with_pip=True, system_site_packages=False).create(env_dir)
    py = str(env_dir / "bin" / "python")
    run([py, "-m", "pip", "install", "-q", "-r", str(REPO / "requirements-ci.txt")], tmp_path)
    run([py, "-m", "pip", "install", "-q", f"{REPO}[mano]"], tmp_path)
    # the installed package, not the checkout: run from elsewhere
    out = run([py, "-m", "oscar_core.cli", "demo", "--out", str(tmp_path / "demo")], tmp_path)
    summary = json.loads((tmp_path / "demo" / "summary.json").read_text())
    rendered = {v["embodiment"] for v in summary["videos"]}
    assert {"franka", "kuka", "agibot_g1", "hsr", "mano"} <= rendered, out
    # the bundled oscar-toy checkpoint is in the wheel (package data) and rolls out from it, offline
    assert summary["toy_world"]["model"] == "oscar-toy" and (tmp_path / "demo" / "toyworld_rollout.mp4").is_file(), out
    probe = (
        "import json, smplx, oscar_core; from oscar_core import get_embodiment; "
        "import oscar_embodiments.mano.mano_model as m; m.require_smplx(); "
        "print(json.dumps({'where': oscar_core.__file__, 'mano': get_embodiment('mano').info()['mano_parameters']}))"
    )
    info = json.loads(run([py, "-c", probe], tmp_path).strip().splitlines()[-1])
    assert str(REPO) not in info["where"] and "available" in info["mano"]
    run([py, "-m", "pip", "uninstall", "-y", "-q", "smplx"], tmp_path)
    check = (
        "import numpy as np\n"
        "from oscar_embodiments.mano import SMPLX_MISSING, trajectory_from_mano\n"
        "try:\n"
        "    trajectory_from_mano({'right': {'global_orient': np.zeros((1, 3)), 'hand_pose': np.zeros((1, 45))}}, 30.0, '/nowhere')\n"
        "except ImportError as exc:\n"
        "    assert str(exc) == SMPLX_MISSING, exc\n"
        "    print('MESSAGE', exc)\n"
    )
    msg = run([py, "-c", check], tmp_path)
    assert 'pip install "oscar-wm[mano]"' in msg

    # a plugin that depends on oscar-wm installs beside it, resolving dependencies (no --no-deps)
    before = installed(py, tmp_path)
    run([py, "-m", "pip", "install", "-q", str(plugin_copy(tmp_path))], tmp_path)
    after = installed(py, tmp_path)
    assert after.pop("oscar-toyarm") == "0.1.0" and after == before  # nothing else installed or replaced
    assert "oscar" not in after and after["oscar-wm"] == oscar_core.__version__
    listing = json.loads(run([py, "-m", "oscar_core.cli", "embodiments", "--json"], tmp_path))
    toyarm = [r for r in listing["embodiments"] if r["name"] == "toyarm"]
    assert len(toyarm) == 1 and "oscar-toyarm" in json.dumps(toyarm[0]), toyarm


def test_plugin_without_oscar_fails_clearly_and_installs_nothing(tmp_path):
    """Without oscar, ``pip install`` of a plugin stops at resolution with a message naming
    oscar-wm, rather than installing the unrelated ``oscar`` project of the package index."""
    env_dir = tmp_path / "bare"
    venv.EnvBuilder(with_pip=True, system_site_packages=False).create(env_dir)
    py = str(env_dir / "bin" / "python")
    before = installed(py, tmp_path)
    proc = run([py, "-m", "pip", "install", str(plugin_copy(tmp_path))], tmp_path, timeout=600, check=False)
    out = proc.stdout + proc.stderr
    assert proc.returncode != 0, out[-3000:]
    assert "No matching distribution found for oscar-wm>=0.1" in out, out[-3000:]
    assert "(from oscar-toyarm" in out, out[-3000:]  # names the plugin that needs it
    after = installed(py, tmp_path)
    assert after == before, (before, after)  # nothing installed: not the plugin, not another "oscar"
