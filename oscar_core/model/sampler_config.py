"""The settings of the rectified-flow sampler: :class:`SamplerConfig` (steps, shift, guidance weight and form,
solver, guidance interval, ...), checked on construction, and :func:`apply_preset`, which sets a named budget's fields
(:data:`~oscar_core.model.presets.SAMPLER_PRESETS`). What each setting does (σ schedule, solvers, guidance forms
and intervals) is documented in :mod:`oscar_core.model.sampler`, which runs them and re-exports these names.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

from .errors import ModelInputError
from .presets import SAMPLER_PRESETS

__all__ = ["GUIDANCE_FORMS", "SOLVERS", "SamplerConfig", "apply_preset"]

GUIDANCE_FORMS = ("standard", "diffusers")
SOLVERS = ("unipc", "euler")


@dataclass(frozen=True)
class SamplerConfig:
    """Sampler settings.

    steps: solver steps (model evaluations per branch) per chunk;
    shift: schedule shift s (the paper trains with 5);
    guidance: w, or None for the conditional branch alone (no second branch);
    guidance_form: "standard" or "diffusers" (module docstring);
    batched_cfg: one forward of batch 2B for both branches;
    cond_timestep: timestep fed for the clean first latent frame (diffusers' 1e-4);
    fps: passed to the DiT's RoPE (None, as the Cosmos 2.5 pipeline does);
    solver: "unipc", "euler", or None for the checkpoint's choice (its
        scheduler config; "unipc" when it has none);
    scheduler_config: a ``UniPCMultistepScheduler`` config (dict) that
        replaces the default flow-sigma one (a checkpoint's ``scheduler/``);
    action_guidance: latent-action models only: w over the actions
        (unconditional branch: no action tokens), None (default): the
        conditional branch alone (module docstring);
    guidance_interval: (lo, hi) noise levels, 0 <= lo <= hi <= 1: guidance
        only at steps with lo <= σ <= hi, the conditional branch alone at the
        others; None (default): every step.
    cond_noise: ours: the noise level σ_c in [0, 1) at which the conditioning
        frame is fed, (1 − σ_c) z_0 + σ_c ε with ε the chunk's initial noise at
        frame 0 and timestep σ_c (at least ``cond_timestep``), for a model trained
        with ``flow.cond_noise_max`` ≥ σ_c; 0 (default): clean, as the paper.
        The chunk's returned frame 0 is the clean latent either way.
    """

    steps: int = 35
    shift: float = 5.0
    guidance: float | None = 6.0
    guidance_form: str = "diffusers"
    batched_cfg: bool = True
    cond_timestep: float = 1e-4
    fps: float | None = None
    solver: str | None = None
    scheduler_config: dict | None = None
    action_guidance: float | None = None
    guidance_interval: tuple[float, float] | None = None
    cond_noise: float = 0.0

    def __post_init__(self):
        if self.guidance_interval is not None:
            iv = self.guidance_interval
            ok = (
                isinstance(iv, (tuple, list))
                and len(iv) == 2
                and all(_finite(v) for v in iv)
                and 0.0 <= float(iv[0]) <= float(iv[1]) <= 1.0
            )
            if not ok:
                raise ModelInputError(
                    f"guidance_interval: expected (lo, hi) noise levels with 0 <= lo <= hi <= 1, found {iv!r}"
                )
            object.__setattr__(self, "guidance_interval", (float(iv[0]), float(iv[1])))
        steps = self.steps
        if isinstance(steps, bool) or not isinstance(steps, numbers.Integral) or steps < 1:
            raise ModelInputError(f"sampler steps: expected an integer >= 1, found {steps!r}")
        if not _finite(self.shift) or not self.shift > 0:
            raise ModelInputError(f"sampler shift: expected a positive finite number, found {self.shift!r}")
        for name in ("guidance", "action_guidance"):
            w = getattr(self, name)
            if w is not None and (not _finite(w) or w < 0):
                raise ModelInputError(
                    f"sampler {name}: expected a finite number >= 0 (or None: the conditional "
                    f"branch alone), found {w!r}"
                )
        if not _finite(self.cond_timestep) or self.cond_timestep < 0:
            raise ModelInputError(f"sampler cond_timestep: expected a finite number >= 0, found {self.cond_timestep!r}")
        if not _finite(self.cond_noise) or not 0.0 <= self.cond_noise < 1.0:
            raise ModelInputError(f"sampler cond_noise: expected a noise level in [0, 1), found {self.cond_noise!r}")
        if self.guidance_form not in GUIDANCE_FORMS:
            raise ModelInputError(f"guidance_form: expected one of {GUIDANCE_FORMS}, found {self.guidance_form!r}")
        if self.solver is not None and self.solver not in SOLVERS:
            raise ModelInputError(
                f"sampler solver: expected one of {SOLVERS} (or None: the checkpoint's), found {self.solver!r}"
            )

    @property
    def resolved_solver(self) -> str:
        """The solver that runs: ``solver``, else "unipc"."""
        return self.solver or "unipc"


def _finite(x) -> bool:
    """A real number (not a bool), neither NaN nor infinite."""
    return isinstance(x, numbers.Real) and not isinstance(x, bool) and math.isfinite(x)


def apply_preset(config: SamplerConfig, name: str | None) -> SamplerConfig:
    """``config`` with the fields of preset ``name`` (None: unchanged); an unknown name is an error."""
    if name is None:
        return config
    if name not in SAMPLER_PRESETS:
        raise ModelInputError(f"sampler preset: expected one of {sorted(SAMPLER_PRESETS)}, found {name!r}")
    from dataclasses import replace

    return replace(config, **SAMPLER_PRESETS[name])
