"""Figures for policy evaluation: success-rate agreement and the two rankings.

* :func:`success_scatter_figure` / :func:`plot_success_scatter` — one point
  per policy at (real success rate, world-model success rate), labelled with
  the policy's name, and the identity line y = x: points on the line are
  policies the world model scores exactly as reality does; the vertical gap
  to the line is that policy's term of SISR_Δ.
* :func:`rank_slope_figure` / :func:`plot_rank_slope` — a slope (bump) chart:
  real ranks on the left, world-model ranks on the right (1 = best, at the
  top), one line per policy; crossing lines are rank violations (MMRV).
* :func:`plot_comparison` — both, from a
  :class:`~oscar_core.metrics.policy.PolicyComparison` (what ``oscar eval
  policies --plot DIR`` writes).

Figures are built on ``matplotlib.figure.Figure`` with the Agg canvas — no
pyplot, no GUI, no global state, safe in threads and on headless machines.
Files are written atomically (a temporary file renamed into place); the format
follows the suffix (``.png``, ``.pdf``, ``.svg``) and ``extra_formats`` writes
siblings with the same stem (e.g. a PDF next to the PNG). PNGs are exactly
``figsize × dpi`` pixels (no tight bounding box). Artists carry ``gid`` s
(``"identity"``, ``"points"``, ``"label:<policy>"``, ``"rank:<policy>"``) so
tests and scripts can find them.

matplotlib is optional: ``pip install "oscar-wm[plots]"``.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from .common import MetricInputError, align_policy_values

__all__ = [
    "success_scatter_figure",
    "rank_slope_figure",
    "save_figure",
    "plot_success_scatter",
    "plot_rank_slope",
    "plot_comparison",
    "descending_ranks",
]

#: Figure size in inches and resolution of the PNGs: 4.8 in × 150 dpi = 720 px.
SCATTER_SIZE = (4.8, 4.8)
SLOPE_SIZE = (5.6, 4.8)
DPI = 150
FORMATS = ("png", "pdf", "svg")


def _matplotlib():
    """matplotlib's Figure and Agg canvas, or an ImportError naming the install command (checked only here)."""
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure
    except ImportError:
        raise ImportError(
            "oscar's evaluation plots need matplotlib, which is not installed; "
            'install it with: pip install "oscar-wm[plots]"'
        ) from None
    return Figure, FigureCanvasAgg


def new_figure(figsize, dpi):
    Figure, FigureCanvasAgg = _matplotlib()
    fig = Figure(figsize=figsize, dpi=dpi)
    FigureCanvasAgg(fig)
    return fig


def descending_ranks(scores) -> np.ndarray:
    """Ranks with 1 = best (highest score); ties share the mean rank. (N,) → (N,) float64."""
    from .policy import average_ranks

    s = np.asarray(scores, dtype=np.float64)
    return len(s) + 1 - average_ranks(s)


def success_scatter_figure(
    real,
    wm,
    *,
    names=None,
    title: str | None = None,
    figsize=SCATTER_SIZE,
    dpi: int = DPI,
    xlabel: str = "real success rate",
    ylabel: str = "world-model success rate",
):
    """A Figure: world-model against real success rate per policy, with the identity line.

    ``real``, ``wm``: per-policy success rates in [0, 1], both mappings
    ``{policy: rate}`` or both sequences with ``names`` (as every policy
    metric takes them). Axes span [0, 1] with a small margin.
    """
    order, r, w = align_policy_values(real, wm, names=names, min_policies=1)
    for side, vals in (("real", r), ("wm", w)):
        for n, v in zip(order, vals):
            if not 0.0 <= v <= 1.0:
                raise MetricInputError(side, n, "a success rate in [0, 1]", v)
    fig = new_figure(figsize, dpi)
    ax = fig.add_subplot(1, 1, 1)
    ax.plot([0.0, 1.0], [0.0, 1.0], linestyle="--", color="0.6", linewidth=1.0, zorder=1, gid="identity", label="y = x")
    ax.scatter(r, w, s=36, color="tab:blue", edgecolor="white", linewidth=0.6, zorder=3, gid="points")
    pad = 0.04
    ax.set_xlim(-pad, 1.0 + pad)
    ax.set_ylim(-pad, 1.0 + pad)
    ax.set_aspect("equal")
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(True, linewidth=0.4, alpha=0.5)
    if title:
        ax.set_title(title, fontsize=10)
    fig.subplots_adjust(left=0.14, right=0.95, bottom=0.11, top=0.92)
    labels = [
        ax.annotate(name, (x, y), xytext=(4, 4), textcoords="offset points", fontsize=8, gid=f"label:{name}", zorder=4)
        for name, x, y in zip(order, r, w)
    ]
    place_labels(fig, ax, labels)
    return fig


#: Offsets (points) and alignment tried for a point's label, in order: right-above, right-below, left-above,
#: left-below, then further up and down on both sides.
_LABEL_SLOTS = [((4, 4), "left"), ((4, -11), "left"), ((-4, 4), "right"), ((-4, -11), "right")] + [
    ((dx, dy), ha)
    for k in range(1, 12)
    for dy in (4 + 10 * k, -11 - 10 * k)
    for dx, ha in (((4, "left"), (-4, "right")))
]


def place_labels(fig, ax, labels) -> None:
    """Move each annotation (in order) to the first slot of :data:`_LABEL_SLOTS` where it overlaps no label
    placed before it and stays inside the axes; the arrow-less label keeps pointing at its own point
    (``xy`` is unchanged). A label with no free slot keeps the first one."""
    renderer = fig.canvas.get_renderer()
    inside = ax.get_window_extent(renderer)
    placed = []
    for label in labels:
        for (dx, dy), ha in _LABEL_SLOTS:
            label.xyann = (dx, dy)
            label.set_horizontalalignment(ha)
            box = label.get_window_extent(renderer)
            fits = box.x0 >= inside.x0 and box.x1 <= inside.x1 and box.y0 >= inside.y0 and box.y1 <= inside.y1
            if fits and not any(box.overlaps(other) for other in placed):
                break
        else:
            label.xyann, _ = _LABEL_SLOTS[0]
            label.set_horizontalalignment("left")
            box = label.get_window_extent(renderer)
        placed.append(box)


def rank_slope_figure(
    real_score,
    wm_score,
    *,
    names=None,
    labels: Sequence[str] = ("real", "world model"),
    title: str | None = None,
    figsize=SLOPE_SIZE,
    dpi: int = DPI,
):
    """A Figure: the two rankings side by side, one line per policy from its real to its world-model rank.

    ``real_score``, ``wm_score``: per-policy ranking scores, higher = better
    (success rates, Elo, BT θ), paired like ``real``/``wm`` elsewhere. Rank 1
    (best) is at the top; tied policies share their mean rank. Each line's data
    is ``x = [0, 1]``, ``y = [real rank, wm rank]`` (gid ``"rank:<policy>"``);
    "name (rank)" is written at both ends (gids ``"label:<policy>:real"`` / ``":wm"``).
    """
    order, r, w = align_policy_values(
        real_score, wm_score, names=names, real_name="real_score", wm_name="wm_score", min_policies=1
    )
    rr, wr = descending_ranks(r), descending_ranks(w)
    n = len(order)
    fig = new_figure(figsize, dpi)
    ax = fig.add_subplot(1, 1, 1)
    colors = [f"C{k % 10}" for k in range(n)]

    def stacked(ranks):  # tied policies share a point: spread their labels vertically (in points)
        offsets = np.zeros(n)
        for value in np.unique(ranks):
            members = np.flatnonzero(ranks == value)
            offsets[members] = (np.arange(len(members)) - (len(members) - 1) / 2) * -10.0
        return offsets

    dy_real, dy_wm = stacked(rr), stacked(wr)
    for k, name in enumerate(order):
        ax.plot(
            [0.0, 1.0], [rr[k], wr[k]], marker="o", color=colors[k], linewidth=1.8, markersize=5, gid=f"rank:{name}"
        )
        ax.annotate(
            f"{name} ({rr[k]:g})",
            (0.0, rr[k]),
            xytext=(-8, dy_real[k]),
            textcoords="offset points",
            ha="right",
            va="center",
            fontsize=8,
            color=colors[k],
            gid=f"label:{name}:real",
        )
        ax.annotate(
            f"({wr[k]:g}) {name}",
            (1.0, wr[k]),
            xytext=(8, dy_wm[k]),
            textcoords="offset points",
            ha="left",
            va="center",
            fontsize=8,
            color=colors[k],
            gid=f"label:{name}:wm",
        )
    ax.set_xlim(-0.05, 1.05)
    ax.set_ylim(n + 0.5, 0.5)  # rank 1 on top
    ax.set_xticks([0.0, 1.0], list(labels))
    ax.set_yticks([])
    ax.tick_params(axis="x", length=0)
    for side in ("top", "right", "bottom", "left"):
        ax.spines[side].set_visible(False)
    if title:
        ax.set_title(title, fontsize=10)
    fig.subplots_adjust(left=0.3, right=0.72, bottom=0.08, top=0.9)
    return fig


def _format_of(path: Path) -> str:
    fmt = path.suffix.lower().lstrip(".")
    if fmt not in FORMATS:
        raise MetricInputError(path, "suffix", f"one of {['.' + f for f in FORMATS]}", repr(path.suffix))
    return fmt


def save_figure(fig, path, *, extra_formats: Sequence[str] = ()) -> Path:
    """Write ``fig`` to ``path`` atomically (format from the suffix), plus ``extra_formats`` siblings.

    Returns ``path``. PNGs are written at the figure's dpi without a tight
    bounding box, so they are exactly ``figsize × dpi`` pixels.
    """
    from .._util.atomic import atomic_output

    path = Path(path)
    targets = [(path, _format_of(path))]
    for fmt in extra_formats:
        fmt = str(fmt).lower().lstrip(".")
        if fmt not in FORMATS:
            raise MetricInputError("extra_formats", "format", f"one of {list(FORMATS)}", repr(fmt))
        sibling = path.with_suffix(f".{fmt}")
        if sibling != path:
            targets.append((sibling, fmt))
    for target, fmt in targets:
        with atomic_output(target) as tmp:
            fig.savefig(tmp, format=fmt, dpi=fig.dpi, metadata={"Software": None} if fmt == "png" else None)
    return path


def plot_success_scatter(real, wm, path, *, extra_formats: Sequence[str] = (), **kwargs) -> Path:
    """:func:`success_scatter_figure` written to ``path`` (see :func:`save_figure`); returns ``path``."""
    return save_figure(success_scatter_figure(real, wm, **kwargs), path, extra_formats=extra_formats)


def plot_rank_slope(real_score, wm_score, path, *, extra_formats: Sequence[str] = (), **kwargs) -> Path:
    """:func:`rank_slope_figure` written to ``path`` (see :func:`save_figure`); returns ``path``."""
    return save_figure(rank_slope_figure(real_score, wm_score, **kwargs), path, extra_formats=extra_formats)


def plot_comparison(comparison, out_dir, *, formats: Sequence[str] = ("png",)) -> dict[str, list[Path]]:
    """Both figures of a :class:`~oscar_core.metrics.policy.PolicyComparison` into ``out_dir`` (created).

    Writes ``success_scatter.<fmt>`` (titled with Pearson r and SISR_Δ) and
    ``rank_slope.<fmt>`` (ranked by the comparison's ranking scores, titled
    with Spearman ρ and MMRV) for each format. Returns ``{"success_scatter":
    [paths], "rank_slope": [paths]}``.
    """
    formats = [str(f).lower().lstrip(".") for f in formats] or ["png"]
    for f in formats:
        if f not in FORMATS:
            raise MetricInputError("formats", "format", f"one of {list(FORMATS)}", repr(f))
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    c = comparison

    def num(v, fmt):
        return "n/a" if v is None or not np.isfinite(v) else format(v, fmt)

    by = c.ranked_by
    scatter = success_scatter_figure(
        dict(zip(c.policies, c.real_success)),
        dict(zip(c.policies, c.wm_success)),
        title=f"Pearson r {num(c.pearson_r, '+.3f')}   SISR\u0394 {num(c.sisr_delta_pp, '.2f')} pp",
    )
    slope = rank_slope_figure(
        dict(zip(c.policies, c.real_score)),
        dict(zip(c.policies, c.wm_score)),
        labels=(f"real\n({by['real']})", f"world model\n({by['wm']})"),
        title=f"Spearman \u03c1 {num(c.spearman_rho, '+.3f')}   MMRV {num(c.mmrv, '.3f')}",
    )
    out = {}
    for stem, fig in (("success_scatter", scatter), ("rank_slope", slope)):
        first = out_dir / f"{stem}.{formats[0]}"
        save_figure(fig, first, extra_formats=formats[1:])
        out[stem] = [out_dir / f"{stem}.{f}" for f in formats]
    return out
