"""Scores of the action-following benchmark from its per-set records, with bootstrap intervals over sets.

A set record (written by :mod:`oscar_core.evaluation.action_following`, one per counterfactual set) holds per
variant the true outcome (``outcome``, 0/1), the world model's verdict (``verdict``: the judge's binary on the
model's video, None when the judge failed on it), the judge's verdict on the true frames (``truth_verdict``, None
without true frames), the located object's end error (``end_error``, ball radii; None when not computed) and per
chunk ``psnr_db`` and ``object_error`` (ball radii).

- **Decision accuracy**: the fraction of sets whose vector of model verdicts over the variants equals the vector
  of true outcomes (every variant right: the outcomes differ exactly as the truth's do).
- **Pairwise rate**: over every set's pairs of variants whose true outcomes differ, the fraction whose model
  verdicts differ too (pooled over sets).
- **Per-variant agreement**: per variant name, the fraction of sets where the verdict equals the truth.
- **Per-chunk drift**: per chunk index, PSNR (dB) and the object error (ball radii), means over the sets (each
  set's mean over its variants).

Every interval is a percentile bootstrap over sets (resampled with replacement, ``resamples`` times, a fixed seed):
the variants of a set, and a second model's verdicts on the same set (:func:`paired_scores`), move together. A
statistic that cannot be computed is a sentence saying why (``{"undefined": "..."}``), never NaN or None.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

__all__ = ["score_records", "paired_scores", "statistic", "format_statistic", "format_summary"]


def _bootstrap(
    per_set: Sequence, fn: Callable[[list], float], resamples: int, seed: int, level: float = 0.95
) -> list[float] | None:
    n = len(per_set)
    if n < 2:
        return None
    rng = np.random.default_rng(seed)
    vals = []
    for _ in range(resamples):
        idx = rng.integers(0, n, n)
        v = fn([per_set[i] for i in idx])
        if np.isfinite(v):
            vals.append(v)
    if not vals:
        return None
    tail = (1 - level) / 2 * 100
    return [float(np.percentile(vals, tail)), float(np.percentile(vals, 100 - tail))]


def statistic(
    per_set: Sequence, fn: Callable[[list], float], *, what: str, resamples: int = 2000, seed: int = 0
) -> dict:
    """``{"value", "ci": [lo, hi], "sets"}`` of ``fn`` over ``per_set`` (one item per set) with its bootstrap
    interval over sets; ``{"undefined": sentence, "sets"}`` when ``fn`` of all the sets is not a finite number
    (``what`` names the statistic in the sentence); an interval over fewer than 2 sets is a sentence too."""
    n = len(per_set)
    if n == 0:
        return {"undefined": f"{what}: no set has what it needs", "sets": 0}
    v = fn(list(per_set))
    if not np.isfinite(v):
        return {"undefined": f"{what}: not defined on these {n} sets (nothing to count)", "sets": n}
    ci = _bootstrap(per_set, fn, resamples, seed)
    out = {"value": float(v), "sets": n}
    if ci is None:
        out["ci_undefined"] = f"an interval needs at least 2 sets, found {n}"
    else:
        out["ci"] = ci
    return out


def _mean(xs) -> float:
    xs = [x for x in xs if x is not None and np.isfinite(x)]
    return float(np.mean(xs)) if xs else float("nan")


def _ratio(pairs) -> float:
    num = sum(p[0] for p in pairs)
    den = sum(p[1] for p in pairs)
    return num / den if den else float("nan")


def _pairs(variants: list[dict]) -> tuple[int, int]:
    """(pairs whose model verdicts differ, pairs whose true outcomes differ) of one set."""
    agree = total = 0
    for i in range(len(variants)):
        for j in range(i + 1, len(variants)):
            a, b = variants[i], variants[j]
            if a["outcome"] == b["outcome"]:
                continue
            total += 1
            agree += int(a["verdict"] is not None and b["verdict"] is not None and a["verdict"] != b["verdict"])
    return agree, total


def _matches(rec: dict) -> int:
    return int(all(v["verdict"] is not None and v["verdict"] == v["outcome"] for v in rec["variants"]))


def _variant_names(records: list[dict]) -> list[str]:
    names: list[str] = []
    for r in records:
        for v in r["variants"]:
            if v["name"] not in names:
                names.append(v["name"])
    return names


def _chunk_means(rec: dict, key: str) -> list[float]:
    n = max((len(v.get("chunks") or []) for v in rec["variants"]), default=0)
    out = []
    for k in range(n):
        out.append(_mean(v["chunks"][k][key] for v in rec["variants"] if len(v.get("chunks") or []) > k))
    return out


def score_records(records: list[dict], *, resamples: int = 2000, seed: int = 0) -> dict:
    """The benchmark's scores of ``records`` (module docstring): ``sets``, ``decision_accuracy``, ``pairwise``,
    ``variants`` (per name: ``agreement``, ``true_rate``, ``model_rate``, ``end_error``, ``judge_on_truth``),
    ``chunks`` (per chunk: ``psnr_db``, ``object_error``), ``judge_failures``."""
    kw = {"resamples": resamples, "seed": seed}
    out: dict = {"sets": len(records)}
    out["decision_accuracy"] = statistic(
        [_matches(r) for r in records], lambda xs: float(np.mean(xs)), what="decision accuracy", **kw
    )
    pairs = [_pairs(r["variants"]) for r in records]
    pairs = [p for p in pairs if p[1] > 0]
    out["pairwise"] = (
        statistic(pairs, _ratio, what="pairwise rate", **kw)
        if pairs
        else {"undefined": "pairwise rate: no set has two variants with different true outcomes", "sets": 0}
    )
    if pairs:
        out["pairwise"]["pairs"] = int(sum(p[1] for p in pairs))
    per_variant = {}
    for name in _variant_names(records):
        rows = [v for r in records for v in r["variants"] if v["name"] == name]
        agree = [int(v["verdict"] is not None and v["verdict"] == v["outcome"]) for v in rows]
        truth_checked = [v for v in rows if v.get("truth_verdict") is not None]
        errs = [v["end_error"] for v in rows if v.get("end_error") is not None]
        per_variant[name] = {
            "agreement": statistic(agree, lambda xs: float(np.mean(xs)), what=f"{name}: agreement", **kw),
            "true_rate": float(np.mean([v["outcome"] for v in rows])),
            "model_rate": statistic(
                [v["verdict"] for v in rows if v["verdict"] is not None],
                lambda xs: float(np.mean(xs)),
                what=f"{name}: model success rate (no verdict)",
                **kw,
            ),
            "end_error": statistic(errs, lambda xs: float(np.mean(xs)), what=f"{name}: object end error", **kw),
            "judge_on_truth": (
                {"agree": sum(int(v["truth_verdict"] == v["outcome"]) for v in truth_checked), "of": len(truth_checked)}
                if truth_checked
                else {"undefined": "no true frames to judge"}
            ),
        }
    out["variants"] = per_variant
    n_chunks = max((len(_chunk_means(r, "psnr_db")) for r in records), default=0)
    chunks = []
    for k in range(n_chunks):
        row = {"chunk": k + 1}
        for key, what in (("psnr_db", "PSNR"), ("object_error", "object error")):
            per = [m[k] for m in (_chunk_means(r, key) for r in records) if len(m) > k and np.isfinite(m[k])]
            row[key] = statistic(per, lambda xs: float(np.mean(xs)), what=f"chunk {k + 1} {what}", **kw)
        chunks.append(row)
    out["chunks"] = chunks if chunks else {"undefined": "no true frames: per-chunk drift needs them"}
    out["judge_failures"] = sum(int(v["verdict"] is None) for r in records for v in r["variants"])
    return out


def paired_scores(records: list[dict], other: list[dict], *, resamples: int = 2000, seed: int = 0) -> dict:
    """This run minus ``other`` (another model's records on the same sets), paired by set id: decision accuracy,
    pairwise rate and per-chunk PSNR, each ``{"value", "ci", "sets"}`` (or a sentence), bootstrap over the sets both
    have."""
    kw = {"resamples": resamples, "seed": seed}
    mine, theirs = {r["set"]: r for r in records}, {r["set"]: r for r in other}
    common = sorted(set(mine) & set(theirs))
    out: dict = {"sets": len(common)}
    if not common:
        return {"sets": 0, "undefined": "the two runs share no set"}
    out["decision_accuracy"] = statistic(
        [_matches(mine[s]) - _matches(theirs[s]) for s in common],
        lambda xs: float(np.mean(xs)),
        what="decision accuracy difference",
        **kw,
    )
    pp = [(_pairs(mine[s]["variants"]), _pairs(theirs[s]["variants"])) for s in common]
    pp = [p for p in pp if p[0][1] > 0 and p[1][1] > 0]
    out["pairwise"] = (
        statistic(
            pp, lambda xs: _ratio([a for a, _ in xs]) - _ratio([b for _, b in xs]), what="pairwise difference", **kw
        )
        if pp
        else {"undefined": "pairwise difference: no shared set has two variants with different true outcomes"}
    )
    chunks = []
    a = {s: _chunk_means(mine[s], "psnr_db") for s in common}
    b = {s: _chunk_means(theirs[s], "psnr_db") for s in common}
    n = max((min(len(a[s]), len(b[s])) for s in common), default=0)
    for k in range(n):
        d = [a[s][k] - b[s][k] for s in common if len(a[s]) > k and len(b[s]) > k and np.isfinite(a[s][k] - b[s][k])]
        chunks.append(
            {"chunk": k + 1, "psnr_db": statistic(d, lambda xs: float(np.mean(xs)), what=f"chunk {k + 1}", **kw)}
        )
    out["chunks"] = chunks
    return out


def format_statistic(s: dict, fmt: str = "{:.3f}", scale: float = 1.0, unit: str = "") -> str:
    """``0.750 [0.500, 1.000]`` (×``scale``, + ``unit``), or the sentence of an undefined statistic."""
    if "undefined" in s:
        return s["undefined"]
    text = fmt.format(s["value"] * scale) + unit
    if "ci" in s:
        lo, hi = s["ci"]
        text += f" [{fmt.format(lo * scale)}, {fmt.format(hi * scale)}]"
    else:
        text += f" ({s['ci_undefined']})"
    return text


def format_summary(report: dict) -> str:
    """The markdown summary of a report (``report.json``'s dict: ``scores``, ``model``, ``settings``, ...)."""
    s = report["scores"]
    mode = str(report.get("mode", ""))
    ceiling = mode.startswith("ceiling")
    how = (
        f"{mode} (no transformer, no sampling: the best any DiT with this autoencoder can score)"
        if ceiling
        else f"sampler {report.get('sampler', '?')}; seed {report.get('seed', '?')}"
    )
    lines = [
        f"# Action following: {report.get('model', '?')}" + (" — autoencoder ceiling" if ceiling else ""),
        "",
        f"{s['sets']} counterfactual sets from `{report.get('manifest', '?')}`; judge `{report.get('judge', '?')}`; "
        f"{how}. Intervals: 95 % bootstrap over sets.",
        "",
        "| score | value [95 % interval] |",
        "|---|---|",
        f"| decision accuracy (every variant's verdict = the truth) | {format_statistic(s['decision_accuracy'], '{:.1f}', 100, ' %')} |",
        f"| pairwise rate (variants with different true outcomes told apart) | "
        f"{format_statistic(s['pairwise'], '{:.1f}', 100, ' %')}"
        + (f" of {s['pairwise']['pairs']} pairs" if "pairs" in s["pairwise"] else "")
        + " |",
        f"| verdicts the judge could not give on the model's videos | {s['judge_failures']} |",
        "",
        "| variant | true success rate | model success rate | verdict = truth | object end error (ball radii) | "
        "judge on the true frames |",
        "|---|---|---|---|---|---|",
    ]
    for name, v in s["variants"].items():
        jt = v["judge_on_truth"]
        jt_text = jt["undefined"] if "undefined" in jt else f"{jt['agree']} of {jt['of']} = truth"
        lines.append(
            f"| {name} | {v['true_rate']:.2f} | {format_statistic(v['model_rate'], '{:.2f}')} | "
            f"{format_statistic(v['agreement'], '{:.2f}')} | {format_statistic(v['end_error'], '{:.2f}')} | {jt_text} |"
        )
    lines.append("")
    if isinstance(s["chunks"], dict):
        lines.append(s["chunks"]["undefined"])
    else:
        lines += ["| chunk | PSNR (dB) | object error (ball radii) |", "|---|---|---|"]
        for c in s["chunks"]:
            lines.append(
                f"| {c['chunk']} | {format_statistic(c['psnr_db'], '{:.2f}')} | "
                f"{format_statistic(c['object_error'], '{:.2f}')} |"
            )
    if report.get("paired"):
        p = report["paired"]
        lines += ["", f"Paired with `{p.get('against', '?')}` (this minus it, same sets: {p.get('sets', 0)}):", ""]
        if "undefined" in p:
            lines.append(p["undefined"])
        else:
            lines += [
                f"- decision accuracy: {format_statistic(p['decision_accuracy'], '{:+.1f}', 100, ' pp')}",
                f"- pairwise rate: {format_statistic(p['pairwise'], '{:+.1f}', 100, ' pp')}",
            ]
            for c in p["chunks"]:
                lines.append(f"- chunk {c['chunk']} PSNR: {format_statistic(c['psnr_db'], '{:+.2f}', 1, ' dB')}")
    if report.get("timing"):
        t = report["timing"]
        lines += [
            "",
            f"Wall {t['wall_s']:.0f} s, CPU {t['cpu_s']:.0f} s this run ({t['sets_run']} sets rolled out, {t['sets_reused']} reused).",
        ]
    return "\n".join(lines) + "\n"
