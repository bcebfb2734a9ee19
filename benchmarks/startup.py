"""Start-up cost of the ``oscar`` command and of a toy rollout's imports: CPU and wall seconds per fresh process.

    python benchmarks/startup.py [--repeats 5] [--before PATH] [--json benchmarks/measured/startup.json]

Each row runs a fresh interpreter ``--repeats`` times from the repository root (the checkout's own code comes
first on sys.path) and reports the median wall seconds from spawn to exit and the median CPU seconds (user + system)
of the process, from ``resource.getrusage(RUSAGE_CHILDREN)``, beside the number of modules it ended up holding and
which of the heavy imports diffusers, transformers and torch._dynamo it held (``heavy``: their names, or "none").
Rows:

- ``python -c pass``: the interpreter and site packages alone (the floor under every command);
- ``oscar --help``, ``oscar rollout --help``, ``oscar zoo list --json``: the command as a user types it;
- ``toy rollout imports``: what ``oscar rollout`` of the bundled ``oscar-toy`` imports before it reads weights (the
  command module, ``rollout_files``, ``world_model`` with oscar's own Cosmos DiT, Wan VAE and UniPC solver, and
  torch);
- ``import torch``, ``import torch + torch._dynamo`` and ``diffusers' DiT + VAE classes`` (torch, then
  ``CosmosTransformer3DModel`` and ``AutoencoderKLWan`` from their own modules, no oscar code): reference floors.
  diffusers imports ``torch._dynamo`` from ``diffusers.utils`` whatever submodule is asked for, and its model base
  classes bring transformers (its quantization config) and scipy (the schedulers, through the single-file loader);
  the third floor is what the toy row cost while the rollout's models were diffusers' classes (the naive way,
  measured in the same run), and the toy row minus ``import torch`` is what oscar's own modules add.

After the repeats, one more process of the toy row runs under ``python -X importtime``; its self times summed per
top-level package (``by_package`` in the JSON: seconds as the importer's clock saw them, wall time inside the
process, and each package's share of their sum) say where a toy rollout's import goes.

``--before PATH``: the same rows run in another checkout (a ``git worktree`` of an older commit, with its
``oscar_embodiments``/``oscar_zoo`` links), alternating with this one repeat by repeat so a change of load hits
both; its rows are labelled ``before`` with its commit (the two floors run here only). The machine's 1-minute load average is in the provenance block.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

#: rows run in this checkout only (the same code in any checkout of oscar)
FLOORS = ("import torch", "import torch + torch._dynamo", "diffusers' DiT + VAE classes")
#: the row whose imports are broken down per top-level package (``by_package``)
TOY = "toy rollout imports"

#: label -> the Python code of the process (``main`` is oscar's CLI entry; SystemExit from --help is the command
#: ending, as in the console script)
PROBE = (
    "import json, sys\n{code}\n"
    "heavy = sorted({{h for h in HEAVY for m in sys.modules if m == h or m.startswith(h + '.')}})\n"
    "print(json.dumps([len(sys.modules), heavy]), file=sys.stderr)\n"
)
#: the imports a toy rollout no longer needs (tests/model/test_rollout_imports.py keeps them out of its path)
HEAVY = ("diffusers", "transformers", "torch._dynamo")
CLI = "from oscar_core.cli import main\ntry:\n    main({argv!r})\nexcept SystemExit:\n    pass"
ROWS: dict[str, str] = {
    "python -c pass": "pass",
    "oscar --help": CLI.format(argv=["--help"]),
    "oscar rollout --help": CLI.format(argv=["rollout", "--help"]),
    "oscar zoo list --json": CLI.format(argv=["zoo", "list", "--json"]),
    TOY: (
        "import oscar_core.cli, oscar_core.model.cli, oscar_core.model.rollout_files\n"
        "import torch\n"
        "from oscar_core.model.world_model import OscarWorldModel"
    ),
    "import torch": "import torch",
    "import torch + torch._dynamo": "import torch, torch._dynamo",
    "diffusers' DiT + VAE classes": (
        "import torch\n"
        "from diffusers.models.transformers.transformer_cosmos import CosmosTransformer3DModel\n"
        "from diffusers.models.autoencoders.autoencoder_kl_wan import AutoencoderKLWan"
    ),
}
#: one line of ``python -X importtime``: self and cumulative microseconds, then the module indented by its depth
IMPORTTIME_LINE = re.compile(r"import time:\s+(\d+) \|\s+(\d+) \|\s*(\S+)")


def probe(code: str) -> str:
    """The program a row's process runs: ``code``, then its module count and heavy imports as JSON on stderr."""
    return PROBE.replace("HEAVY", repr(HEAVY)).format(code=code)


def run_once(code: str, cwd: Path) -> tuple[float, float, int, list[str]]:
    """(wall s, CPU s, modules held at the end, heavy imports held) of one fresh interpreter running ``code`` in
    ``cwd``."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-c", probe(code)],
        cwd=cwd,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "OMP_NUM_THREADS": "1", "HF_HUB_OFFLINE": "1"},
    )
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise SystemExit(f"startup: {code!r} in {cwd} exited {proc.returncode}: {proc.stderr.strip()[-500:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    modules, heavy = json.loads(proc.stderr.strip().splitlines()[-1])
    return wall, cpu, int(modules), list(heavy)


def by_package(importtime: str, top: int = 10) -> list[dict]:
    """``python -X importtime``'s report (its stderr) summed per top-level package: one record per package, the
    ``top`` largest by self time then ``other``, each with ``self_s`` (seconds; the importer's own clock, wall time
    in the process), ``share`` of the sum and the number of ``modules``. Self times, not cumulative ones, so each
    module counts once, under its own package (``torch._dynamo`` under ``torch``)."""
    seconds: dict[str, float] = {}
    modules: dict[str, int] = {}
    for line in importtime.splitlines():
        m = IMPORTTIME_LINE.match(line)
        if m is None:  # the header line and anything else the process wrote
            continue
        package = m.group(3).split(".")[0]
        seconds[package] = seconds.get(package, 0.0) + int(m.group(1)) / 1e6
        modules[package] = modules.get(package, 0) + 1
    total = sum(seconds.values())
    ranked = sorted(seconds, key=lambda p: (-seconds[p], p))
    rows = [(p, seconds[p], modules[p]) for p in ranked[:top]]
    rest = ranked[top:]
    if rest:
        rows.append(("other", sum(seconds[p] for p in rest), sum(modules[p] for p in rest)))
    return [
        {"package": p, "self_s": round(s, 3), "share": round(s / total, 3) if total else 0.0, "modules": n}
        for p, s, n in rows
    ]


def importtime_of(code: str, cwd: Path) -> str:
    """The ``-X importtime`` report of one fresh interpreter running ``code`` in ``cwd``."""
    proc = subprocess.run(
        [sys.executable, "-X", "importtime", "-c", probe(code)],
        cwd=cwd,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "OMP_NUM_THREADS": "1", "HF_HUB_OFFLINE": "1"},
    )
    if proc.returncode != 0:
        raise SystemExit(f"startup: -X importtime {code!r} in {cwd} exited {proc.returncode}")
    return proc.stderr


def print_packages(packages: list[dict]) -> None:
    print(f"\n{TOY}, self time per top-level package (-X importtime, one process):")
    print(f"{'package':<22} {'self s':>7} {'share':>6} {'modules':>8}")
    for p in packages:
        print(f"{p['package']:<22} {p['self_s']:>7.3f} {p['share']:>6.1%} {p['modules']:>8}")


def commit_of(checkout: Path) -> str:
    proc = subprocess.run(
        ["git", "-C", str(checkout), "rev-parse", "--short=12", "HEAD"], capture_output=True, text=True
    )
    return proc.stdout.strip() or "unknown"


def measure(checkouts: dict[str, Path], repeats: int) -> list[dict]:
    """One row per (checkout, probe): medians over ``repeats``, the checkouts alternating within each repeat."""
    runs: dict[tuple[str, str], list[tuple[float, float, int, list[str]]]] = {}
    for _ in range(repeats):
        for label, code in ROWS.items():
            for name, path in checkouts.items():
                if label in FLOORS and path != REPO:
                    continue
                runs.setdefault((name, label), []).append(run_once(code, path))
    return [
        {
            "checkout": name,
            "commit": commit_of(checkouts[name]),
            "what": label,
            "repeats": repeats,
            "cpu_s": round(statistics.median(run[1] for run in r), 3),
            "wall_s": round(statistics.median(run[0] for run in r), 3),
            "wall_s_max": round(max(run[0] for run in r), 3),
            "modules": r[-1][2],
            "heavy": ", ".join(r[-1][3]) or "none",
        }
        for (name, label), r in runs.items()
    ]


def print_table(rows: list[dict]) -> None:
    print(f"{'checkout':<22} {'what':<30} {'CPU s':>7} {'wall s':>7} {'wall max':>9} {'modules':>8}  heavy imports")
    for r in sorted(rows, key=lambda r: (list(ROWS).index(r["what"]), r["checkout"])):
        print(
            f"{r['checkout'] + ' ' + r['commit']:<22} {r['what']:<30} {r['cpu_s']:>7.3f} {r['wall_s']:>7.3f} "
            f"{r['wall_s_max']:>9.3f} {r['modules']:>8}  {r['heavy']}"
        )


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=5, help="processes per row (median; default 5)")
    ap.add_argument("--before", type=Path, help="another checkout to measure alongside (e.g. an older commit)")
    ap.add_argument("--json", type=Path, help="write the rows here (benchmarks/measured/startup.json)")
    args = ap.parse_args(argv)
    if args.repeats < 1:
        ap.error(f"--repeats: expected at least 1, found {args.repeats}")
    checkouts = {"this": REPO}
    if args.before is not None:
        if not (args.before / "oscar_core" / "cli.py").is_file():
            ap.error(f"--before {args.before}: expected a checkout of oscar (oscar_core/cli.py), found none")
        checkouts["before"] = args.before.resolve()
    rows = measure(checkouts, args.repeats)
    print_table(rows)
    packages = by_package(importtime_of(ROWS[TOY], REPO))
    print_packages(packages)
    if args.json:
        sys.path.insert(0, str(REPO / "benchmarks"))
        sys.path.insert(0, str(REPO))
        from _provenance import with_provenance

        from oscar_core._util.atomic import atomic_write_bytes

        result = with_provenance({"benchmark": "startup", "rows": rows, "by_package": packages})
        print(f"wrote {atomic_write_bytes(args.json, (json.dumps(result, indent=2) + chr(10)).encode())}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
