"""``python -m oscar_core.metrics.policy_seeds RUN [RUN ...]``: parse, summarise
(:func:`~oscar_core.metrics.policy_seeds.summarize_runs`), print (the per-policy rates, Spearman ρ with its
session interval, P(ρ ≥ 0.8), Pearson r, MMRV and SISR_Δ).

Exit codes: 0, 1 when some run judged fewer cells than it holds (PARTIAL), 2 for bad input.
"""

from __future__ import annotations

import argparse
import json
import sys

from .._util.arg_types import count
from .common import MetricInputError
from .policy_seeds import summarize_runs

__all__ = ["main"]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m oscar_core.metrics.policy_seeds",
        description="Policy evaluation averaged over rollout seeds: per-policy rates, "
        "Spearman rho with a session bootstrap, Pearson r, MMRV, SISR.",
    )
    parser.add_argument(
        "runs",
        nargs="+",
        metavar="RUN",
        help="`oscar eval run` output folders, one per rollout seed, over the same manifest's cells "
        "(or `oscar eval closed-loop` folders, one per noise seed, with --truth)",
    )
    parser.add_argument(
        "--truth",
        metavar="SIM_RUN",
        help="closed-loop runs: the same manifest's `oscar eval closed-loop --simulator` folder (the real outcomes)",
    )
    parser.add_argument("--resamples", type=count(1), default=2000, help="session bootstrap resamples (2000)")
    parser.add_argument("--seed", type=count(0), default=0, help="bootstrap seed (0)")
    parser.add_argument(
        "--pair",
        action="append",
        metavar="A,B",
        help="two policies whose cell-by-cell separation to report (repeatable; default: the truth's best and worst)",
    )
    parser.add_argument("--json", action="store_true", help="print the summary as JSON")
    args = parser.parse_args(argv)
    pairs = None
    if args.pair:
        pairs = [tuple(x.strip() for x in p.split(",")) for p in args.pair]
        bad = [p for p in args.pair if len(p.split(",")) != 2]
        if bad:
            print(f"error: --pair: expected two policy names A,B, found {bad[0]!r}", file=sys.stderr)
            return 2
    try:
        s = summarize_runs(args.runs, args.resamples, args.seed, args.truth, pairs=pairs)
    except MetricInputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(s, indent=2))
    else:
        print(
            f"{len(s['runs'])} runs, {s['sessions']} sessions; judged cells per run: "
            + ", ".join(f"{j}/{n}" for j, n in s["judged"])
        )
        print(
            "policy: real / world model: "
            + ", ".join(f"{p} {r:.2f} / {w:.3f}" for p, r, w in zip(s["policies"], s["real_success"], s["wm_success"]))
        )
        why = s["undefined"]

        def figure(key: str, text) -> str:
            return text(s[key]) if s[key] is not None else f"undefined ({why[key]})"

        print(
            "Spearman "
            + figure("spearman_rho", lambda v: f"{v:+.3f}")
            + (
                f" [{s['spearman_ci95'][0]:+.2f}, {s['spearman_ci95'][1]:+.2f}]"
                if s["spearman_ci95"]
                else (f", no interval ({why['spearman_ci95']})" if s["spearman_rho"] is not None else "")
            )
        )
        print("P(rho >= 0.8) " + figure("p_rho_at_least_0_8", lambda v: f"{v:.3f}"))
        print("Pearson " + figure("pearson_r", lambda v: f"{v:+.3f}"))
        print(
            "MMRV "
            + figure("mmrv", lambda v: f"{v:.3f}")
            + ", SISR "
            + figure("sisr_delta_pp", lambda v: f"{v:.2f} pp")
        )
        _print_cells(s["cells"])
    if not s["complete"]:
        print(
            "warning: PARTIAL: some runs judged fewer cells than they hold (judged cells per run: "
            + ", ".join(f"{j}/{n}" for j, n in s["judged"])
            + "); those cells average fewer seeds",
            file=sys.stderr,
        )
        return 1
    return 0


def _print_cells(c: dict) -> None:
    """The cell-by-cell lines: agreement and κ with their intervals, then each pair's separation, undefined ones in
    words."""

    def ci(key: str, fmt: str) -> str:
        v = c.get(key)
        return f" [{v[0]:{fmt}}, {v[1]:{fmt}}]" if v else f", no interval ({c.get('ci95_why') or 'none defined'})"

    agree = "undefined (no cell judged by both)" if c["agreement"] is None else f"{c['agreement']:.3f}"
    agree += ci("agreement_ci95", ".2f") if c["agreement"] is not None else ""
    kappa = (
        f"{c['kappa']:+.3f}{ci('kappa_ci95', '+.2f')}" if c["kappa"] is not None else f"undefined ({c['kappa_why']})"
    )
    print(f"cells: verdict = truth in {agree} of {c['cells_judged']} cells; Cohen's kappa {kappa}")
    for name, p in c["pairs"].items():
        if p["separated"] is None:
            print(f"{name}: undefined ({p['why']})")
            continue
        interval = f" [{p['ci95'][0]:.2f}, {p['ci95'][1]:.2f}]" if p.get("ci95") else ""
        print(
            f"{name}: told apart the right way round in {p['separated']:.3f}{interval} of the "
            f"{p['sessions']} sessions the truth tells them apart"
        )


if __name__ == "__main__":
    raise SystemExit(main())
