"""The sampler settings a model card recommends, and how an entry point resolves them: :func:`check_card_sampler`
checks a card's ``sampler`` (a mapping of :data:`CARD_SAMPLER_KEYS`: steps, guidance, guidance_form, preset), and
:func:`resolve_sampler` picks each setting from the caller, else the card, else the library default, returning a
:class:`SamplerChoice` (the :class:`~oscar_core.model.sampler_config.SamplerConfig` and where each setting came
from). Re-exported by :mod:`oscar_core.model.sampler`.
"""

from __future__ import annotations

import numbers
from collections.abc import Mapping
from dataclasses import dataclass

from .errors import ModelInputError
from .presets import SAMPLER_PRESETS
from .sampler_config import GUIDANCE_FORMS, SamplerConfig, _finite, apply_preset

__all__ = [
    "CARD_SAMPLER_KEYS",
    "SamplerChoice",
    "check_card_sampler",
    "resolve_sampler",
    "sampler_with_scheduler",
    "sampler_of_card",
]

#: the sampler settings a model card may recommend (``ModelCard.sampler``), each a :func:`resolve_sampler` option
CARD_SAMPLER_KEYS = ("steps", "guidance", "guidance_form", "preset")
#: where a setting came from, by priority (highest first)
GIVEN, CARD, DEFAULT = "given", "model card", "library default"


def check_card_sampler(value, source: str = "model card sampler") -> dict | None:
    """``value`` (a card's ``sampler``: a mapping of :data:`CARD_SAMPLER_KEYS`, or None) checked, as a plain dict;
    a :class:`ModelInputError` names the key, what was expected and what was found."""
    if value is None:
        return None
    if not isinstance(value, Mapping):
        raise ModelInputError(f"{source}: expected a mapping of {', '.join(CARD_SAMPLER_KEYS)}, found {value!r}")
    unknown = sorted(set(value) - set(CARD_SAMPLER_KEYS))
    if unknown:
        raise ModelInputError(f"{source}: expected keys among {', '.join(CARD_SAMPLER_KEYS)}, found {unknown}")
    out = dict(value)
    if "steps" in out and (
        isinstance(out["steps"], bool) or not isinstance(out["steps"], numbers.Integral) or out["steps"] < 1
    ):
        raise ModelInputError(f"{source}.steps: expected an integer >= 1, found {out['steps']!r}")
    if "guidance" in out and out["guidance"] is not None and (not _finite(out["guidance"]) or out["guidance"] < 0):
        raise ModelInputError(f"{source}.guidance: expected a finite number >= 0, found {out['guidance']!r}")
    if "guidance_form" in out and out["guidance_form"] not in GUIDANCE_FORMS:
        raise ModelInputError(
            f"{source}.guidance_form: expected one of {GUIDANCE_FORMS}, found {out['guidance_form']!r}"
        )
    if "preset" in out and out["preset"] is not None and out["preset"] not in SAMPLER_PRESETS:
        raise ModelInputError(
            f"{source}.preset: expected one of {sorted(SAMPLER_PRESETS)} or null, found {out['preset']!r}"
        )
    return out


@dataclass(frozen=True)
class SamplerChoice:
    """A sampler and where each recommended setting came from: ``sources[key]`` is ``"given"`` (a flag or
    argument), ``"model card"`` or ``"library default"`` for each of :data:`CARD_SAMPLER_KEYS` (steps set by a
    preset: ``"preset fast (given)"``)."""

    config: SamplerConfig
    sources: dict
    preset: str | None = None

    def describe(self, given: str = "given") -> str:
        """One line, e.g. ``steps 20 (model card), guidance 3 (model card), guidance form diffusers (model card),
        preset none (library default)``; ``given`` names the explicit source (``"flag"`` on the command line)."""
        c = self.config
        values = {
            "steps": c.steps,
            "guidance": "none" if c.guidance is None else f"{c.guidance:g}",
            "guidance_form": c.guidance_form,
            "preset": self.preset or "none",
        }
        return ", ".join(
            f"{k.replace('_', ' ')} {values[k]} ({self.sources[k].replace(GIVEN, given)})" for k in CARD_SAMPLER_KEYS
        )


def resolve_sampler(
    card_sampler=None,
    *,
    steps: int | None = None,
    guidance: float | None = None,
    guidance_form: str | None = None,
    preset: str | None = None,
    guidance_interval: tuple[float, float] | None = None,
    defaults=None,
    **fields,
) -> SamplerChoice:
    """The sampler an entry point runs: each of steps, guidance, guidance form and preset from the caller when
    given (not None), else from the model card's recommendation ``card_sampler`` (``ModelCard.sampler``), else
    the library default (35 steps, guidance 6, the diffusers form, no preset; ``defaults`` overrides these per
    entry point). A preset sets steps and the guidance interval; steps given at the same or a higher level
    (caller over card over default) replace the preset's. ``guidance_interval`` given replaces the preset's;
    ``fields`` (shift, solver, batched_cfg, action_guidance, ...) go to :class:`SamplerConfig` as they are.
    """
    from dataclasses import replace

    rank = {GIVEN: 2, CARD: 1, DEFAULT: 0}
    lib = {"steps": 35, "guidance": 6.0, "guidance_form": "diffusers", "preset": None, **dict(defaults or {})}
    card = check_card_sampler(card_sampler) or {}
    asked = {"steps": steps, "guidance": guidance, "guidance_form": guidance_form, "preset": preset}
    value, sources = {}, {}
    for key in CARD_SAMPLER_KEYS:
        if asked[key] is not None:
            value[key], sources[key] = asked[key], GIVEN
        elif key in card:
            value[key], sources[key] = card[key], CARD
        else:
            value[key], sources[key] = lib[key], DEFAULT
    config = apply_preset(
        SamplerConfig(guidance=value["guidance"], guidance_form=value["guidance_form"], **fields), value["preset"]
    )
    if value["preset"] is not None and rank[sources["preset"]] > rank[sources["steps"]]:
        sources["steps"] = f"preset {value['preset']} ({sources['preset']})"
    else:
        config = replace(config, steps=value["steps"])
    if guidance_interval is not None:
        config = replace(config, guidance_interval=guidance_interval)
    return SamplerChoice(config, sources, value["preset"])


def sampler_with_scheduler(sampler: SamplerConfig, scheduler_config: dict | None) -> SamplerConfig:
    """``sampler`` with a checkpoint's choices filled in from its scheduler config (``scheduler_config.json``, or
    None): a solver left open (``solver=None``) becomes Euler for a ``FlowMatchEulerDiscreteScheduler`` and UniPC
    otherwise; UniPC takes the checkpoint's ``UniPCMultistepScheduler`` config when ``sampler`` gives none."""
    from dataclasses import replace

    cfg = scheduler_config or {}
    unipc = dict(cfg) if cfg.get("_class_name") == "UniPCMultistepScheduler" else None
    if sampler.solver is not None:
        if sampler.solver == "unipc" and sampler.scheduler_config is None and unipc is not None:
            return replace(sampler, scheduler_config=unipc)
        return sampler
    if cfg.get("_class_name") == "FlowMatchEulerDiscreteScheduler":
        return replace(sampler, solver="euler")
    return replace(sampler, solver="unipc", scheduler_config=sampler.scheduler_config or unipc)


def sampler_of_card(card_sampler, scheduler_config: dict | None = None, **given) -> SamplerConfig:
    """The sampler a checkpoint describes: :func:`resolve_sampler` of its card's ``sampler`` under the ``given``
    options (none: the card's recommendation, else the library defaults), its solver from ``scheduler_config``
    (:func:`sampler_with_scheduler`)."""
    return sampler_with_scheduler(resolve_sampler(card_sampler, **given).config, scheduler_config)
