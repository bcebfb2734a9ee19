"""The metric networks an evaluation command uses: given on the command line, else from the weights cache.

One place resolves them for ``oscar eval video`` and ``oscar eval benchmark table``:
an explicit network (a TorchScript file or ``module:attr``, :func:`load_network`)
wins; otherwise the standard networks fetched by ``oscar eval weights pull``
(hash-checked, :func:`oscar_core.metrics.weights.cached_networks`) are used
unless ``use_cache`` is False; latent L2's VAE is the project's VAE of
``vae_model`` from the local model cache. Nothing is downloaded: a network
that is not available leaves its metric out, with the reason in ``notes``.
"""

from __future__ import annotations

import importlib
from pathlib import Path

from .common import MetricInputError

__all__ = ["load_network", "resolve_networks"]


def load_network(spec: str | None, what: str):
    """A TorchScript path is returned as is (loaded by the metric); ``module:attr`` is imported and called."""
    if spec is None:
        return None
    if spec.endswith((".pt", ".pth", ".ts")) or Path(spec).is_file():
        if not Path(spec).is_file():
            raise MetricInputError(spec, what, "an existing TorchScript file", "no such file")
        return spec
    if ":" not in spec:
        raise MetricInputError(spec, what, "a TorchScript file (.pt) or module:attr", repr(spec))
    mod_name, attr = spec.split(":", 1)
    try:
        obj = getattr(importlib.import_module(mod_name), attr)
    except (ImportError, AttributeError) as exc:
        raise MetricInputError(spec, what, "an importable module:attr", f"{type(exc).__name__}: {exc}") from exc
    if not callable(obj):
        raise MetricInputError(spec, what, "a callable that returns the network", type(obj).__name__)
    return obj()


def resolve_networks(
    *, lpips=None, i3d=None, inception=None, vae=None, vae_model: str = "none", use_cache: bool = True, device="cpu"
) -> tuple[dict, list[str], dict]:
    """(networks {lpips, i3d, inception, vae: network or None}, names taken from the cache, notes {key: why not}).

    lpips, i3d, inception, vae: specs as :func:`load_network` takes them
    (None: not given); vae_model: a checkpoint whose VAE computes latent L2
    when ``vae`` is not given, from the local cache only ("none": skip).
    """
    nets = {
        "lpips": load_network(lpips, "--lpips"),
        "i3d": load_network(i3d, "--i3d"),
        "inception": load_network(inception, "--inception"),
        "vae": load_network(vae, "--vae"),
    }
    used_cache: list[str] = []
    notes: dict[str, str] = {}
    if use_cache:
        from .weights import cached_networks

        for key, net in cached_networks(device=device).items():
            if nets.get(key) is None:
                nets[key] = net
                used_cache.append(key)
    for key in ("lpips", "i3d", "inception"):
        if nets[key] is None:
            notes[key] = f"no --{key} network given" + (
                " and none in the weights cache (`oscar eval weights pull`)" if use_cache else " (--no-cached-networks)"
            )
    if nets["vae"] is None and vae_model != "none":
        from .project_vae import load_project_vae

        try:
            nets["vae"] = load_project_vae(vae_model, device=device)
        except Exception as exc:  # noqa: BLE001 - not cached / not a checkpoint: latent L2 is skipped, and said so
            notes["latent_l2"] = (
                f"skipped: the VAE of {vae_model!r} is not available locally "
                f"({type(exc).__name__}: {str(exc)[:200]}); `oscar zoo pull {vae_model}` or "
                "--vae / --vae-model FOLDER"
            )
    elif nets["vae"] is None:
        notes["vae"] = "no --vae network given (--vae-model none)"
    return nets, used_cache, notes
