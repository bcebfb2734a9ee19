"""Named sampling budgets, without importing torch (the CLIs list them in ``--help``).

Each preset sets fields of :class:`~oscar_core.model.sampler.SamplerConfig`; the rest (e.g. the guidance
weight) stay the model's or the user's. ``paper``: the paper's 35 UniPC steps, guidance at every step.
``fast`` was chosen from its measured quality against ``paper`` on the toy model (docs/world-model.md,
"Sampling presets").
"""

from __future__ import annotations

from typing import Literal

__all__ = ["SAMPLER_PRESETS", "PresetName"]

#: the names of the sampler presets
PresetName = Literal["paper", "fast"]

SAMPLER_PRESETS: dict[PresetName, dict] = {
    "paper": {"steps": 35, "guidance_interval": None},
    "fast": {"steps": 12, "guidance_interval": (0.0, 0.8)},
}
