"""Evaluation plots: files, sizes, and the plotted data read back from the figure's artists (not pixels)."""

import argparse
import json
import struct
import sys

import numpy as np
import pytest

pytest.importorskip("matplotlib")

from oscar_core.metrics import (
    MetricInputError,
    add_eval_parser,
    compare_policies,
    plot_comparison,
    plot_rank_slope,
    plot_success_scatter,
    rank_slope_figure,
    save_figure,
    success_scatter_figure,
)

REAL = {"pi0_flow": 0.30, "pi0_fast": 0.50, "pg_bin": 0.10, "pg_fast": 0.45, "pg_fsq": 0.10}
WM = {"pi0_flow": 0.35, "pi0_fast": 0.40, "pg_bin": 0.15, "pg_fast": 0.50, "pg_fsq": 0.20}


def png_size(path):
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and data[12:16] == b"IHDR"
    return struct.unpack(">II", data[16:24])  # (width, height)


def by_gid(fig, gid):
    found = fig.findobj(lambda a: a.get_gid() == gid)
    assert len(found) == 1, (gid, found)
    return found[0]


def test_success_scatter_plots_the_input():
    fig = success_scatter_figure(REAL, WM, title="t")
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    assert isinstance(fig.canvas, FigureCanvasAgg)
    points = by_gid(fig, "points")
    assert np.allclose(points.get_offsets(), np.c_[list(REAL.values()), [WM[p] for p in REAL]])
    identity = by_gid(fig, "identity")
    assert np.allclose(identity.get_xdata(), [0, 1]) and np.allclose(identity.get_ydata(), [0, 1])
    for name in REAL:
        label = by_gid(fig, f"label:{name}")
        assert label.get_text() == name and np.allclose(label.xy, (REAL[name], WM[name]))
    ax = fig.axes[0]
    assert ax.get_xlim()[0] < 0 < 1 < ax.get_xlim()[1] and ax.get_ylim()[0] < 0 < 1 < ax.get_ylim()[1]
    assert ax.get_title() == "t" and ax.get_xlabel() == "real success rate"
    # sequences with names, same result
    fig2 = success_scatter_figure([0.2, 0.8], [0.3, 0.6], names=["a", "b"])
    assert np.allclose(by_gid(fig2, "points").get_offsets(), [[0.2, 0.3], [0.8, 0.6]])
    assert by_gid(fig2, "label:b").get_text() == "b"


def test_success_scatter_labels_never_overlap_and_stay_inside():
    # crowded: two points on top of each other, three close together, one in a corner
    real = {"pi0_flow": 0.5, "pi0_fast": 0.5, "pg_bin": 0.1, "pg_fast": 0.12, "pg_fsq": 0.11, "octo_base": 1.0}
    wm = {"pi0_flow": 0.5, "pi0_fast": 0.5, "pg_bin": 0.2, "pg_fast": 0.21, "pg_fsq": 0.19, "octo_base": 1.0}
    fig = success_scatter_figure(real, wm)
    renderer = fig.canvas.get_renderer()
    inside = fig.axes[0].get_window_extent(renderer)
    boxes = {n: by_gid(fig, f"label:{n}").get_window_extent(renderer) for n in real}
    for a in real:
        assert np.allclose(by_gid(fig, f"label:{a}").xy, (real[a], wm[a]))  # still pointing at its own point
        assert (
            inside.x0 <= boxes[a].x0
            and boxes[a].x1 <= inside.x1
            and inside.y0 <= boxes[a].y0 <= boxes[a].y1 <= inside.y1
        )
        for b in real:
            assert a == b or not boxes[a].overlaps(boxes[b]), (a, b)


def test_rank_slope_plots_both_rankings_with_ties():
    fig = rank_slope_figure(REAL, WM, labels=("RoboArena", "OSCAR"))
    # real: pi0_fast 1, pg_fast 2, pi0_flow 3, pg_bin / pg_fsq tied 4.5; wm: pg_fast 1, pi0_fast 2, ...
    expected = {"pi0_fast": (1, 2), "pg_fast": (2, 1), "pi0_flow": (3, 3), "pg_bin": (4.5, 5), "pg_fsq": (4.5, 4)}
    for name, (r, w) in expected.items():
        line = by_gid(fig, f"rank:{name}")
        assert np.allclose(line.get_xdata(), [0, 1]) and np.allclose(line.get_ydata(), [r, w])
        left, right = by_gid(fig, f"label:{name}:real"), by_gid(fig, f"label:{name}:wm")
        assert left.get_text() == f"{name} ({r:g})" and right.get_text() == f"({w:g}) {name}"
        assert np.allclose(left.xy, (0, r)) and np.allclose(right.xy, (1, w))
    ax = fig.axes[0]
    assert ax.get_ylim()[0] > ax.get_ylim()[1]  # rank 1 at the top
    assert [t.get_text() for t in ax.get_xticklabels()] == ["RoboArena", "OSCAR"]
    # tied labels are spread apart, not drawn on top of each other
    assert by_gid(fig, "label:pg_bin:real").xyann != by_gid(fig, "label:pg_fsq:real").xyann


def test_files_are_written_atomically_with_the_expected_size(tmp_path):
    out = plot_success_scatter(REAL, WM, tmp_path / "scatter.png", extra_formats=("pdf",), dpi=100, figsize=(4, 3))
    assert out == tmp_path / "scatter.png"
    assert png_size(out) == (400, 300)
    assert (tmp_path / "scatter.pdf").read_bytes()[:5] == b"%PDF-"
    out = plot_rank_slope(REAL, WM, tmp_path / "ranks.png")
    assert png_size(out) == (840, 720)  # default 5.6 x 4.8 in at 150 dpi
    svg = plot_rank_slope(REAL, WM, tmp_path / "ranks.svg")
    assert b"<svg" in svg.read_bytes()[:500]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ranks.png", "ranks.svg", "scatter.pdf", "scatter.png"]
    # a failed save leaves nothing behind, and does not touch an existing file
    before = (tmp_path / "scatter.png").read_bytes()

    class Boom(Exception):
        pass

    fig = success_scatter_figure(REAL, WM)
    fig.savefig = lambda *a, **k: (_ for _ in ()).throw(Boom())
    with pytest.raises(Boom):
        save_figure(fig, tmp_path / "scatter.png")
    assert (tmp_path / "scatter.png").read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ranks.png", "ranks.svg", "scatter.pdf", "scatter.png"]


def test_plot_comparison_and_bad_input(tmp_path):
    comparison = compare_policies(REAL, WM)
    written = plot_comparison(comparison, tmp_path / "figs", formats=("png", "pdf"))
    assert written == {
        "success_scatter": [tmp_path / "figs" / "success_scatter.png", tmp_path / "figs" / "success_scatter.pdf"],
        "rank_slope": [tmp_path / "figs" / "rank_slope.png", tmp_path / "figs" / "rank_slope.pdf"],
    }
    assert png_size(written["success_scatter"][0]) == (720, 720)
    assert all(p.stat().st_size > 1000 for paths in written.values() for p in paths)
    with pytest.raises(MetricInputError, match="suffix"):
        plot_success_scatter(REAL, WM, tmp_path / "x.jpg")
    with pytest.raises(MetricInputError, match="success rate"):
        success_scatter_figure({"a": 42.0, "b": 0.5}, {"a": 0.4, "b": 0.5})
    with pytest.raises(MetricInputError, match="policy names"):
        rank_slope_figure({"a": 1, "b": 2}, {"a": 1, "c": 2})
    with pytest.raises(MetricInputError, match="format"):
        plot_comparison(comparison, tmp_path, formats=("gif",))


def test_missing_matplotlib_names_the_install_command(monkeypatch):
    monkeypatch.setitem(sys.modules, "matplotlib.figure", None)
    with pytest.raises(ImportError, match=r"pip install \"oscar-wm\[plots\]\""):
        success_scatter_figure(REAL, WM)


def test_cli_eval_policies_plot(tmp_path, capsys):
    (tmp_path / "real.json").write_text(json.dumps(REAL))
    (tmp_path / "wm.json").write_text(json.dumps({p: {"success_rate": v} for p, v in WM.items()}))
    parser = argparse.ArgumentParser(prog="oscar")
    add_eval_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(
        [
            "eval",
            "policies",
            "--real",
            str(tmp_path / "real.json"),
            "--wm",
            str(tmp_path / "wm.json"),
            "--plot",
            str(tmp_path / "figs"),
            "--plot-format",
            "png,pdf",
            "--json",
        ]
    )
    assert args.func(args) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["plots"]["success_scatter"] == [str(tmp_path / "figs" / f"success_scatter.{f}") for f in ("png", "pdf")]
    assert sorted(p.name for p in (tmp_path / "figs").iterdir()) == [
        "rank_slope.pdf",
        "rank_slope.png",
        "success_scatter.pdf",
        "success_scatter.png",
    ]
    args = parser.parse_args(
        [
            "eval",
            "policies",
            "--real",
            str(tmp_path / "real.json"),
            "--wm",
            str(tmp_path / "wm.json"),
            "--plot",
            str(tmp_path / "f2"),
        ]
    )
    assert args.func(args) == 0
    assert "wrote " + str(tmp_path / "f2" / "rank_slope.png") in capsys.readouterr().out
    args = parser.parse_args(
        [
            "eval",
            "policies",
            "--real",
            str(tmp_path / "real.json"),
            "--wm",
            str(tmp_path / "wm.json"),
            "--plot",
            str(tmp_path / "f3"),
            "--plot-format",
            "bmp",
        ]
    )
    with pytest.raises(MetricInputError, match="--plot-format"):
        args.func(args)
