"""The Wan VAE's RMS norm on its reference path, for benchmarks that measure both paths in one run."""

from __future__ import annotations

import contextlib


@contextlib.contextmanager
def f_normalize_rms_norm():
    """Inside: oscar's Wan ``RMSNorm`` normalises through ``F.normalize`` everywhere, as diffusers' ``WanRMS_norm``
    does (and oscar did before ``channel_norm_by_sums``); the sum-of-squares path comes back on exit."""
    from oscar_core.model import _wan_vae_layers as layers

    applies = layers._sum_norm_applies
    layers._sum_norm_applies = lambda x: False
    try:
        yield
    finally:
        layers._sum_norm_applies = applies
