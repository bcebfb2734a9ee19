"""Start-up cost of the ``oscar`` command and of a toy rollout's imports: CPU and wall seconds per fresh process.

    python benchmarks/startup.py [--repeats 5] [--before PATH] [--json benchmarks/measured/startup.json]

Each row runs a fresh interpreter ``--repeats`` times from the repository root (the checkout's own code comes
first on sys.path) and reports the median wall seconds from spawn to exit and the median CPU seconds (user + system)
of the process, from ``resource.getrusage(RUSAGE_CHILDREN)``, beside the number of modules it ended up holding.
Rows:

- ``python -c pass``: the interpreter and site packages alone (the floor under every command);
- ``oscar --help``, ``oscar rollout --help``, ``oscar zoo list --json``: the command as a user types it;
- ``toy rollout imports``: what ``oscar rollout`` of the bundled ``oscar-toy`` imports before it reads weights (the
  command module, ``rollout_files``, ``world_model`` with diffusers' Cosmos DiT and WAN VAE, and torch);
- ``import torch`` and ``import torch + torch._dynamo``: reference floors (diffusers imports ``torch._dynamo`` from
  ``diffusers.utils`` whatever submodule is asked for, so a rollout through diffusers pays both).

``--before PATH``: the same rows run in another checkout (a ``git worktree`` of an older commit, with its
``oscar_embodiments``/``oscar_zoo`` links), alternating with this one repeat by repeat so a change of load hits
both; its rows are labelled ``before`` with its commit (the two floors run here only). The machine's 1-minute load average is in the provenance block.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

#: rows run in this checkout only (the same code in any checkout of oscar)
FLOORS = ("import torch", "import torch + torch._dynamo")

#: label -> the Python code of the process (``main`` is oscar's CLI entry; SystemExit from --help is the command
#: ending, as in the console script)
PROBE = "import sys\n{code}\nprint(len(sys.modules), file=sys.stderr)\n"
CLI = "from oscar_core.cli import main\ntry:\n    main({argv!r})\nexcept SystemExit:\n    pass"
ROWS: dict[str, str] = {
    "python -c pass": "pass",
    "oscar --help": CLI.format(argv=["--help"]),
    "oscar rollout --help": CLI.format(argv=["rollout", "--help"]),
    "oscar zoo list --json": CLI.format(argv=["zoo", "list", "--json"]),
    "toy rollout imports": (
        "import oscar_core.cli, oscar_core.model.cli, oscar_core.model.rollout_files\n"
        "import torch\n"
        "from oscar_core.model.world_model import OscarWorldModel"
    ),
    "import torch": "import torch",
    "import torch + torch._dynamo": "import torch, torch._dynamo",
}


def run_once(code: str, cwd: Path) -> tuple[float, float, int]:
    """(wall s, CPU s, modules held at the end) of one fresh interpreter running ``code`` in ``cwd``."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-c", PROBE.format(code=code)],
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
    return wall, cpu, int(proc.stderr.strip().splitlines()[-1])


def commit_of(checkout: Path) -> str:
    proc = subprocess.run(
        ["git", "-C", str(checkout), "rev-parse", "--short=12", "HEAD"], capture_output=True, text=True
    )
    return proc.stdout.strip() or "unknown"


def measure(checkouts: dict[str, Path], repeats: int) -> list[dict]:
    """One row per (checkout, probe): medians over ``repeats``, the checkouts alternating within each repeat."""
    runs: dict[tuple[str, str], list[tuple[float, float, int]]] = {}
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
            "cpu_s": round(statistics.median(c for _, c, _ in r), 3),
            "wall_s": round(statistics.median(w for w, _, _ in r), 3),
            "wall_s_max": round(max(w for w, _, _ in r), 3),
            "modules": r[-1][2],
        }
        for (name, label), r in runs.items()
    ]


def print_table(rows: list[dict]) -> None:
    print(f"{'checkout':<22} {'what':<30} {'CPU s':>7} {'wall s':>7} {'wall max':>9} {'modules':>8}")
    for r in sorted(rows, key=lambda r: (list(ROWS).index(r["what"]), r["checkout"])):
        print(
            f"{r['checkout'] + ' ' + r['commit']:<22} {r['what']:<30} {r['cpu_s']:>7.3f} {r['wall_s']:>7.3f} "
            f"{r['wall_s_max']:>9.3f} {r['modules']:>8}"
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
    if args.json:
        sys.path.insert(0, str(REPO / "benchmarks"))
        sys.path.insert(0, str(REPO))
        from _provenance import with_provenance

        from oscar_core._util.atomic import atomic_write_bytes

        result = with_provenance({"benchmark": "startup", "rows": rows})
        print(f"wrote {atomic_write_bytes(args.json, (json.dumps(result, indent=2) + chr(10)).encode())}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
