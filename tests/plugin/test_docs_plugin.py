"""Runs every code block of docs/write-a-plugin.md, as a reader would.

Blocks with ``title="path"`` are written to that path in a scratch folder;
``console`` blocks are run line by line. The commands run inside a virtual
environment made for the test (``--system-site-packages``, so oscar and its
dependencies come from the test environment): ``oscar`` is the CLI,
``python`` its interpreter and ``pip install`` installs there, offline
(``--no-deps --no-build-isolation``), so the test never changes the
environment it runs in.
"""

import json
import re
import subprocess
import sys
import venv
from pathlib import Path

import pytest
from _paths import REPO

DOC = REPO / "docs" / "write-a-plugin.md"
BLOCK = re.compile(r"^```(\w+)(?:[ \t]+title=\"([^\"]+)\")?[ \t]*\n(.*?)^```[ \t]*$", re.M | re.S)


def doc_blocks():
    return [(lang, title, body) for lang, title, body in BLOCK.findall(DOC.read_text())]


def test_doc_has_the_steps_we_run():
    blocks = doc_blocks()
    titles = [t for _, t, _ in blocks if t]
    assert {"twolink.urdf", "twolink.py", "make_inputs.py", "oscar-twolink/pyproject.toml"} <= set(titles)
    assert sum(lang == "console" for lang, _, _ in blocks) >= 3


@pytest.mark.slow
def test_docs_plugin_walkthrough(tmp_path):
    env_dir = tmp_path / "venv"
    venv.EnvBuilder(system_site_packages=True, with_pip=False).create(env_dir)
    py = str(env_dir / "bin" / "python")
    # system_site_packages shows the base interpreter's packages, not those of a virtual environment the tests
    # may run in: add the running interpreter's site-packages (their .pth files too: editable installs)
    import sysconfig

    site_dir = subprocess.run(
        [py, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    parents = sorted({sysconfig.get_paths()["purelib"], sysconfig.get_paths()["platlib"]})
    Path(site_dir, "_tests_parent_env.pth").write_text(
        "".join(f"import site; site.addsitedir({d!r})\n" for d in parents)
    )
    work = tmp_path / "work"
    work.mkdir()
    outputs = []
    for lang, title, body in doc_blocks():
        if title:
            target = work / title
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_text(body)
            continue
        if lang != "console":
            continue
        for line in body.splitlines():
            if not line.startswith("$ "):
                continue
            cmd = line[2:].strip()
            cmd = re.sub(r"^oscar\b", f"{py} -m oscar_core.cli", cmd)
            cmd = re.sub(r"^python\b", py, cmd)
            cmd = re.sub(
                r"^pip install\b",
                f"{sys.executable} -m pip --python {py} install --no-deps --no-build-isolation -q",
                cmd,
            )
            proc = subprocess.run(cmd, shell=True, cwd=work, capture_output=True, text=True, timeout=300)
            assert proc.returncode == 0, f"`{line}` failed:\n{proc.stdout}\n{proc.stderr}"
            outputs.append((line, proc.stdout))
    listing = dict(outputs)
    one_file = json.loads(listing["$ oscar --plugin twolink.py embodiments --json"])
    twolink = [e for e in one_file["embodiments"] if e["name"] == "twolink"]
    assert twolink and twolink[0]["joints"] == 2 and twolink[0]["distribution"].startswith("file:")
    # the packaged plugin shows up without --plugin, with its distribution and version
    table = listing["$ oscar embodiments"]
    row = [l for l in table.splitlines() if l.startswith("twolink")]
    assert row and "oscar-twolink 0.1.0" in row[0], table
    from oscar_core.media.video import read_video

    video = read_video(work / "twolink.mp4")
    assert video.shape == (81, 384, 512, 3) and video.max() > 0
