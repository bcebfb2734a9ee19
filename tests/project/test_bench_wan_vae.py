"""benchmarks/wan_vae.py: its in-process part runs both classes on a toy chunk and finds them equal; bad settings
are refused before any work."""

import importlib.util

import pytest
from _paths import REPO

pytest.importorskip("diffusers")


def _bench():
    spec = importlib.util.spec_from_file_location("bench_wan_vae", REPO / "benchmarks" / "wan_vae.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_compute_rows_cover_both_classes_both_norms_and_both_parts_and_agree():
    import torch

    threads = torch.get_num_threads()
    try:
        rows = _bench().measure_compute(1)
    finally:
        torch.set_num_threads(threads)
    assert {(r["vae"], r["part"]) for r in rows} == {
        (v, p)
        for v in ("oscar WanVAE", "oscar WanVAE, F.normalize norm", "diffusers AutoencoderKLWan")
        for p in ("encode", "decode")
    }
    assert all(r["max_abs_diff"] == 0.0 and r["cpu_ms"] > 0 for r in rows)


def test_the_f_normalize_row_turns_the_sum_of_squares_norm_off_and_back_on(monkeypatch):
    import torch

    from oscar_core.model import _wan_vae_layers as layers

    monkeypatch.syspath_prepend(str(REPO / "benchmarks"))
    from _wan_norm import f_normalize_rms_norm

    x = torch.ones(1, 16, 2, 32, 32)
    with torch.no_grad():
        assert layers._sum_norm_applies(x)
        with f_normalize_rms_norm():
            assert not layers._sum_norm_applies(x)
        assert layers._sum_norm_applies(x)


def test_zero_repeats_are_refused(tmp_path, capsys):
    assert _bench().main(["--repeats", "0", "--json", str(tmp_path / "out.json")]) == 2
    assert "--repeats: expected at least 1, found 0" in capsys.readouterr().err
    assert not (tmp_path / "out.json").exists()


def test_encode_variants_state_their_difference_and_put_the_model_back(monkeypatch):
    import torch

    mod = _bench()
    seen = []  # (turned on?, 5-D weights in channels-last after the call)
    real = mod._channels_last

    def spy(model, on):
        real(model, on)
        last = [p for p in model.parameters() if p.ndim == 5 and not p.is_contiguous()]
        seen.append((on, sum(p.is_contiguous(memory_format=torch.channels_last_3d) for p in last)))

    monkeypatch.setattr(mod, "_channels_last", spy)
    threads = torch.get_num_threads()
    try:
        rows = mod.measure_encode_variants(1, ("as it is", "channels-last"))
    finally:
        torch.set_num_threads(threads)
    assert [r["variant"] for r in rows] == ["as it is", "channels-last"]
    as_is, last = rows
    assert as_is["max_abs_diff"] == 0.0 and as_is["cpu_vs_as_it_is"] == 1.0 and as_is["cpu_ms"] > 0
    assert last["max_abs_diff"] < 1e-4  # not bit-identical on oneDNN: the tolerance the JSON states
    on = [i for i, (turned_on, n) in enumerate(seen) if turned_on]
    assert on and all(seen[i][1] > 0 for i in on)  # the weights really were channels-last
    assert all(seen[i + 1] == (False, 0) for i in on)  # and contiguous again right after


def test_encode_variants_only_needs_an_existing_file(tmp_path, capsys):
    assert _bench().main(["--encode-variants-only", "--json", str(tmp_path / "none.json")]) == 2
    assert "none.json: expected a file this benchmark wrote, found none" in capsys.readouterr().err
