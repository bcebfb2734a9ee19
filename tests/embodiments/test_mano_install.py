"""The ``mano`` extra: its metadata pulls smplx, and oscar works without it.

smplx is installed system-wide here, so a virtual environment with system
site packages would not prove anything, and one without them would need
torch and the rest of oscar's dependencies offline. So:

1. the wheel metadata of this checkout is built with the PEP 517 hook pip
   itself calls (``setuptools.build_meta.prepare_metadata_for_build_wheel``,
   in a subprocess, output in a temporary folder; the checkout is not
   touched) and its METADATA must declare ``Requires-Dist: smplx...;
   extra == "mano"``;
2. "smplx missing" is emulated in a fresh interpreter by a ``sys.meta_path``
   finder that refuses to find ``smplx``: the keypoint path renders, the
   MANO-parameter path raises ImportError with exactly the documented
   message, and ``oscar embodiments --json`` still lists ``mano`` and says
   what is missing.
"""

import json
import re
import subprocess
import sys
import textwrap

import pytest
from _paths import REPO

from oscar_embodiments.mano import SMPLX_MISSING

pytestmark = pytest.mark.slow


def test_wheel_metadata_declares_the_mano_extra(tmp_path):
    code = (
        "import sys; from setuptools import build_meta; print(build_meta.prepare_metadata_for_build_wheel(sys.argv[1]))"
    )
    run = subprocess.run(
        [sys.executable, "-c", code, str(tmp_path)], cwd=REPO, capture_output=True, text=True, timeout=120
    )
    assert run.returncode == 0, run.stderr[-2000:]
    dist_info = run.stdout.strip().splitlines()[-1]
    metadata = (tmp_path / dist_info / "METADATA").read_text()
    assert "Provides-Extra: mano" in metadata
    reqs = re.findall(r"^Requires-Dist: (.*)$", metadata, flags=re.M)
    mano = [r for r in reqs if re.search(r"""extra\s*==\s*["']mano["']""", r)]
    assert len(mano) == 1 and re.match(r"smplx\s*>=\s*0\.1\.28\s*;", mano[0]), reqs
    assert not any(r.startswith("smplx") and "extra" not in r for r in reqs)  # not a core dependency


BLOCKED = textwrap.dedent('''
    import json, sys

    class NoSmplx:
        """Behaves as if smplx were not installed."""
        def find_spec(self, name, path=None, target=None):
            if name == "smplx" or name.startswith("smplx."):
                raise ModuleNotFoundError(f"No module named {name!r}", name=name)
            return None

    sys.meta_path.insert(0, NoSmplx())
    out = {}

    import numpy as np
    from oscar_core import render_skeleton_video
    from oscar_embodiments.mano import Mano, egocentric_camera, trajectory_from_keypoints, trajectory_from_mano
    from oscar_embodiments.mano.synthetic import hand_keypoints

    kp = np.stack([np.stack([hand_keypoints(0.3, side="left"), hand_keypoints(0.3)])] * 2) + [0, 0, 0.4]
    video = render_skeleton_video(Mano(), trajectory_from_keypoints(kp, 30.0), egocentric_camera(200, 200, 63.5, 63.5, 128, 128))
    out["keypoint_path_pixels"] = int((video > 0).sum())
    try:
        trajectory_from_mano({"right": {"global_orient": np.zeros((1, 3)), "hand_pose": np.zeros((1, 45))}}, 30.0, "/nowhere")
        out["mano_path"] = "no error"
    except ImportError as exc:
        out["mano_path"] = str(exc)

    import contextlib, io
    from oscar_core.cli import main
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        main(["embodiments", "--json"])
    listing = json.loads(buf.getvalue())
    out["listed"] = [r for r in listing["embodiments"] if r["name"] == "mano"]
    out["smplx_imported"] = "smplx" in sys.modules
    print("RESULT" + json.dumps(out))
''')


def test_without_smplx_keypoints_work_and_mano_parameters_say_how_to_install():
    run = subprocess.run([sys.executable, "-c", BLOCKED], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-3000:]
    out = json.loads(run.stdout.split("RESULT", 1)[1])
    assert out["keypoint_path_pixels"] > 0
    assert out["mano_path"] == SMPLX_MISSING
    assert 'pip install "oscar-wm[mano]"' in out["mano_path"]
    assert len(out["listed"]) == 1 and "error" not in out["listed"][0]
    assert out["listed"][0]["mano_parameters"] == SMPLX_MISSING
    assert not out["smplx_imported"]
