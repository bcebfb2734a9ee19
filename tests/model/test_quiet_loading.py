"""Loading a checkpoint's VAE prints nothing but real problems.

diffusers' ``from_pretrained`` logs a hint about installing ``accelerate`` on
every load where that package is absent (it is not a dependency of oscar).
Every oscar load path builds the diffusers modules itself
(``oscar_core.model.vae.load_vae_folder``), so the hint never shows, while a
real warning — oscar's own, diffusers' or Python's — still reaches stderr.
Each check runs in a fresh interpreter: diffusers' log handler binds stderr
when diffusers is first imported.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

HINT = "accelerate"


def _run(code: str, *args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    env.pop("OSCAR_VERBOSITY", None)
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code), *args],
        check=False,
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )


def test_loading_the_bundled_vae_is_quiet_and_real_warnings_still_show():
    proc = _run("""
        import warnings
        from oscar_core._util.log import configure_cli, get_logger
        configure_cli()  # what the oscar command sets up
        from oscar_core.metrics.project_vae import load_project_vae
        encode = load_project_vae("oscar-toy")
        print(encode.source)
        get_logger("oscar_core.metrics.project_vae").warning("a real oscar warning")
        from diffusers.utils import logging as dlog
        dlog.get_logger("diffusers.models.modeling_utils").warning("a real diffusers warning")
        warnings.warn("a real python warning")
        """)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip().endswith("oscar-toy")
    assert HINT not in proc.stderr, proc.stderr
    for line in ("warning: a real oscar warning", "a real diffusers warning", "a real python warning"):
        assert line in proc.stderr, proc.stderr


def test_eval_video_with_the_toy_vae_prints_no_hint(tmp_path):
    """The command a user runs: latent L2 through ``--vae-model oscar-toy``."""
    rng = np.random.default_rng(0)
    for name in ("pred", "gt"):
        np.save(tmp_path / f"{name}.npy", rng.integers(0, 256, (5, 32, 32, 3), dtype=np.uint8))
    proc = _run(
        """
        import sys
        from oscar_core.cli import main
        sys.exit(main(sys.argv[1:]))
        """,
        "eval",
        "video",
        str(tmp_path / "pred.npy"),
        str(tmp_path / "gt.npy"),
        "--frames",
        "0",
        "--json",
        "--no-cached-networks",
        "--vae-model",
        "oscar-toy",
    )
    assert proc.returncode == 0, proc.stderr
    assert '"latent_l2"' in proc.stdout
    assert HINT not in proc.stderr, proc.stderr


def test_the_strict_loader_matches_diffusers_own(one_thread):
    """A second implementation: diffusers' ``from_pretrained`` gives the same weights and the same latents."""
    import torch
    from diffusers import AutoencoderKLWan

    import oscar_zoo
    from oscar_core.metrics.project_vae import load_project_vae
    from oscar_core.model.vae import VideoVAE, load_vae_folder

    folder = oscar_zoo.pull("oscar-toy", local_files_only=True) / "vae"
    ours = load_vae_folder(folder)
    theirs = AutoencoderKLWan.from_pretrained(str(folder), use_safetensors=True, low_cpu_mem_usage=False)
    a, b = ours.state_dict(), theirs.state_dict()
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    x = torch.rand(1, 3, 5, 32, 32) * 2 - 1
    with torch.no_grad():
        assert torch.equal(load_project_vae("oscar-toy")(x), VideoVAE(theirs).encode(x))


@pytest.mark.parametrize("bad", ["missing", "class"])
def test_the_strict_loader_refuses_a_broken_folder(tmp_path, bad):
    import json
    import shutil

    import oscar_zoo
    from oscar_core.model.errors import CheckpointLayoutError
    from oscar_core.model.vae import load_vae_folder

    src = oscar_zoo.pull("oscar-toy", local_files_only=True) / "vae"
    folder = shutil.copytree(src, tmp_path / "vae")
    if bad == "missing":
        (folder / "diffusion_pytorch_model.safetensors").unlink()
    else:
        cfg = json.loads((folder / "config.json").read_text())
        (folder / "config.json").write_text(json.dumps({**cfg, "_class_name": "AutoencoderKL"}))
    with pytest.raises(CheckpointLayoutError, match="vae"):
        load_vae_folder(folder)
