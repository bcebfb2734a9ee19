"""Multistep UniPC for rectified flow, torch and numpy only: oscar's own solver, numerically diffusers 0.42.1's.

UniPC (Zhao et al. 2023, "UniPC: A Unified Predictor-Corrector Framework for Fast Sampling of Diffusion Models",
arXiv:2302.04867) integrates in the log signal-to-noise ratio λ = log α − log σ. For the flow
z_σ = (1 − σ) z_0 + σ ε the signal scale is α = 1 − σ, and a velocity v (≈ ε − z_0) gives the data prediction
x̂ = z − σ v. Step i goes from σ_i to σ_{i+1} (h = λ_{i+1} − λ_i) and does three things:

1. the velocity at (z_i, σ_i) gives x̂_i (z_i as the previous predictor left it; x̂_i is what is remembered);
2. the corrector (UniC), from the second step on: z_i is recomputed from z_{i−1} with x̂_i now known, at the
   order the previous predictor used (unless that step is in ``disable_corrector``);
3. the predictor (UniP): z_{i+1} from z_i and the last p data predictions.

Both updates from a state z at (σ, α, λ) to (σ', α', λ') with newest prediction x̂ read
``z' = (σ'/σ) z − α' (e^{−h} − 1) x̂ − α' B(h) Σ_k ρ_k D_k``, where each older prediction x̂_k (at λ_k) enters as
D_k = (x̂_k − x̂) / r_k with r_k = (λ_k − λ) / h, and the corrector adds D = x̂_new − x̂ with r = 1. B(h) is
e^{−h} − 1 (``"bh2"``, the default) or −h (``"bh1"``). The weights ρ solve R ρ = b with R_jk = r_k^j and
b_j = j! ψ_j / B(h), ψ_1 = (e^{−h} − 1)/(−h) − 1, ψ_{j+1} = ψ_j/(−h) − 1/(j+1)!; the predictor solves the system
without the new node (order 2: ρ = 1/2 outright) and the corrector the whole one (order 1: ρ = 1/2 outright).

Orders: step i uses at most ``min(order, i + 1)`` predictions (the first step is first order), and with
``lower_order_final`` at most ``steps − i`` (the last step is first order, the one before at most second). On the
last step to σ = 0, λ' = +∞, e^{−h} − 1 = −1 and the first-order update lands exactly on x̂.

Schedule (:func:`flow_schedule`): u = linspace(1, 1/T, steps + 1) less its last value (T = ``train_steps``, 1000),
shifted as σ = s·u / (1 + (s − 1)·u) in float64; σ_0 is lowered by 1e-6 when it is 1 within 1e-6 (λ would be −∞).
With ``karras=(sigma_min, sigma_max)`` (a checkpoint's ``use_karras_sigmas``, as diffusers' Cosmos conversions
write) the levels are instead Karras et al.'s: the noise-to-signal ratio σ/(1 − σ) spaced uniformly in its 7th root
from sigma_max down to sigma_min over ``steps`` levels, then mapped back to σ; no shift. Then one more level is
appended, 0 (``final_sigma="zero"``) or the last σ again (``"sigma_min"``), and the levels are kept as float32. The
integer timesteps ⌊T σ⌋ are informational: steps are counted, not looked up, so a long schedule whose first two
timesteps coincide (about 1000 / shift steps and more) runs here, while diffusers' class then starts at its second
entry and stops on an assertion at the last step.

Arithmetic: each coefficient is a float32 0-dim tensor on the state's device, computed from the float32 levels in
the order diffusers computes it, and the state keeps its own dtype (float64 stays float64); so this solver and
diffusers' ``UniPCMultistepScheduler`` give the same states bit for bit (tests/model/test_unipc.py; measured at
orders 1 to 3). From order 3 on the weighted sum of differences is summed here term by term where diffusers calls
einsum, so there equality is promised to rounding only.

Which scheduler configs run here (:func:`solver_for_config`; the rest still run through diffusers' class, imported
only then, by :func:`oscar_core.model.sampler.unipc_scheduler`): flow sigmas with ``flow_prediction`` and
``predict_x0``; any ``solver_order``; ``solver_type`` bh1 or bh2; ``lower_order_final``; ``disable_corrector``;
``final_sigmas_type`` zero or sigma_min; ``flow_shift``; ``num_train_timesteps``; ``use_karras_sigmas`` with both
``sigma_min`` and ``sigma_max`` given; and the settings that flow sigmas never read (betas, timestep spacing and
offset, threshold ratio). Karras sigmas without both bounds (diffusers derives them from the betas), exponential or
beta sigmas, dynamic shifting, ``shift_terminal``, thresholding, ``solver_p`` and any setting not named here go to
diffusers.

Where the two differ: with ``solver_type="bh1"`` and a last level of 0, diffusers' last step multiplies
B(h) = −∞ by its empty sum and returns NaN; here the empty sum is left out and the step lands on x̂, as bh2 does.
``lower_order_final=False`` on a schedule ending at 0 ends in ±∞ here as there (its second-order last step divides
by r = 0).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
import torch

__all__ = ["FlowUniPC", "flow_schedule", "solver_for_config"]

VARIANTS = ("bh1", "bh2")
FINAL_SIGMAS = ("zero", "sigma_min")


def flow_schedule(
    steps: int,
    shift: float = 1.0,
    train_steps: int = 1000,
    final_sigma: str = "zero",
    karras: tuple[float, float] | None = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """``(sigmas, timesteps)`` of a UniPC flow schedule (module docstring): (steps + 1,) float32 noise levels, the
    last 0 (or the previous level with ``final_sigma="sigma_min"``), and (steps,) int64 timesteps ⌊train_steps σ⌋.

    karras: ``(sigma_min, sigma_max)``: Karras et al.'s spacing instead of the shifted linear one (module
    docstring); ``shift`` is then unused."""
    if isinstance(steps, bool) or int(steps) != steps or steps < 1:
        raise ValueError(f"UniPC steps: expected an integer >= 1, found {steps!r}")
    if final_sigma not in FINAL_SIGMAS:
        raise ValueError(f"UniPC final_sigma: expected one of {FINAL_SIGMAS}, found {final_sigma!r}")
    if karras is None:
        u = np.linspace(1.0, 1.0 / train_steps, int(steps) + 1)[:-1]
        levels = shift * u / (1 + (shift - 1) * u)
        if abs(levels[0] - 1.0) < 1e-6:
            levels[0] -= 1e-6  # λ = log(1 − σ) − log σ is −∞ at σ = 1
    else:
        levels = _karras_levels(int(steps), *karras)
    timesteps = torch.from_numpy((levels * train_steps).astype(np.int64))
    last = levels[-1] if final_sigma == "sigma_min" else 0.0
    sigmas = torch.from_numpy(np.append(levels, last).astype(np.float32))
    return sigmas, timesteps


#: Karras et al.'s ρ: the spacing is uniform in σ_edm^(1/ρ)
KARRAS_RHO = 7.0


def _karras_levels(steps: int, sigma_min: float, sigma_max: float) -> np.ndarray:
    """(steps,) float64 flow levels σ_edm / (1 + σ_edm), σ_edm spaced uniformly in σ_edm^(1/7) from ``sigma_max``
    down to ``sigma_min`` (Karras et al. 2022, "Elucidating the Design Space of Diffusion-Based Generative Models",
    eq. 5), σ_edm being the noise-to-signal ratio σ/(1 − σ) of the flow."""
    top, bottom = sigma_max ** (1 / KARRAS_RHO), sigma_min ** (1 / KARRAS_RHO)
    edm = (top + np.linspace(0, 1, steps) * (bottom - top)) ** KARRAS_RHO
    return edm / (edm + 1)


def _log_snr(sigma: torch.Tensor) -> torch.Tensor:
    """λ = log α − log σ of a 0-dim float32 level, α = 1 − σ (+∞ at σ = 0)."""
    return torch.log(1 - sigma) - torch.log(sigma)


class FlowUniPC:
    """Multistep UniPC predictor-corrector over a rectified-flow schedule (module docstring).

    shift: the flow shift s of the schedule; order: the most predictions a step combines (2: second order, as
    Cosmos-Predict2.5 samples); variant: ``"bh2"`` or ``"bh1"``, the B(h) of the update; lower_order_final: lower
    the order on the last steps; disable_corrector: predictor steps whose correction is skipped; final_sigma:
    ``"zero"`` or ``"sigma_min"``; train_steps: T of the schedule; karras: ``(sigma_min, sigma_max)`` for Karras
    spacing (then ``shift`` is unused). Call :meth:`set_timesteps`, then :meth:`step`
    once per entry of ``timesteps`` with the velocity at ``sigmas[i]``.
    """

    def __init__(
        self,
        shift: float = 1.0,
        order: int = 2,
        variant: str = "bh2",
        lower_order_final: bool = True,
        disable_corrector: Sequence[int] = (),
        final_sigma: str = "zero",
        train_steps: int = 1000,
        karras: tuple[float, float] | None = None,
    ) -> None:
        if isinstance(order, bool) or int(order) != order or order < 1:
            raise ValueError(f"UniPC order: expected an integer >= 1, found {order!r}")
        if variant not in VARIANTS:
            raise ValueError(f"UniPC variant: expected one of {VARIANTS}, found {variant!r}")
        if final_sigma not in FINAL_SIGMAS:
            raise ValueError(f"UniPC final_sigma: expected one of {FINAL_SIGMAS}, found {final_sigma!r}")
        if not (isinstance(shift, (int, float)) and not isinstance(shift, bool) and math.isfinite(shift) and shift > 0):
            raise ValueError(f"UniPC shift: expected a finite number > 0, found {shift!r}")
        self.shift = float(shift)
        self.order = int(order)
        self.variant = variant
        self.lower_order_final = bool(lower_order_final)
        self.disable_corrector = frozenset(int(i) for i in disable_corrector)
        self.final_sigma = final_sigma
        self.train_steps = int(train_steps)
        if karras is not None and not (len(karras) == 2 and 0 < karras[0] < karras[1] and math.isfinite(karras[1])):
            raise ValueError(f"UniPC karras: expected (sigma_min, sigma_max) with 0 < min < max, found {karras!r}")
        self.karras = None if karras is None else (float(karras[0]), float(karras[1]))
        self.sigmas: torch.Tensor | None = None
        self.timesteps: torch.Tensor | None = None

    def __repr__(self) -> str:
        return (
            f"FlowUniPC(shift={self.shift}, order={self.order}, variant={self.variant!r}, "
            f"lower_order_final={self.lower_order_final}, disable_corrector={sorted(self.disable_corrector)}, "
            f"final_sigma={self.final_sigma!r}, train_steps={self.train_steps}, karras={self.karras})"
        )

    def set_timesteps(self, steps: int, device: torch.device | str | None = None) -> None:
        """Lay out ``steps`` steps (``sigmas`` float32 on the CPU, ``timesteps`` int64 on ``device``) and forget
        any previous run."""
        self.sigmas, timesteps = flow_schedule(steps, self.shift, self.train_steps, self.final_sigma, self.karras)
        self.timesteps = timesteps.to(device)
        self._index = 0
        self._predictions: list[torch.Tensor] = []  # x̂ of the last steps, oldest first
        self._start: torch.Tensor | None = None  # the state the last predictor started from
        self._start_order = 0  # and the order it used

    def step(self, velocity: torch.Tensor, sample: torch.Tensor) -> torch.Tensor:
        """The state at ``sigmas[i + 1]`` from ``sample`` at ``sigmas[i]`` and the ``velocity`` there (step i).

        velocity, sample: tensors of one shape; returns sample's dtype and shape."""
        if self.sigmas is None:
            raise RuntimeError("FlowUniPC.step: call set_timesteps(steps) first")
        i = self._index
        if i >= len(self.timesteps):
            raise RuntimeError(f"FlowUniPC.step: all {len(self.timesteps)} steps are taken; call set_timesteps again")
        predicted = sample - self.sigmas[i].to(sample.device) * velocity
        if self._start is not None and i - 1 not in self.disable_corrector:
            sample = self._update(self._start, i - 1, self._start_order, newest=predicted)
        self._predictions = (self._predictions + [predicted])[-self.order :]
        order = len(self._predictions)  # min(order, i + 1): the warm-up
        if self.lower_order_final:
            order = min(order, len(self.timesteps) - i)
        self._start, self._start_order = sample, order
        self._index = i + 1
        return self._update(sample, i, order)

    def _update(self, x: torch.Tensor, i: int, order: int, newest: torch.Tensor | None = None) -> torch.Tensor:
        """One UniP (``newest`` None) or UniC (``newest``: x̂ at level i + 1) update of ``x`` from level i to
        i + 1 at ``order``, using the remembered predictions, the last of which is at level i."""
        device = x.device
        level = [self.sigmas[i - k].to(device) for k in range(order)]  # level[k]: σ of the k-th newest prediction
        target = self.sigmas[i + 1].to(device)
        lam = _log_snr(level[0])
        h = _log_snr(target) - lam
        latest = self._predictions[-1]
        nodes, diffs = [], []
        for k in range(1, order):
            r = (_log_snr(level[k]) - lam) / h
            nodes.append(r)
            diffs.append((self._predictions[-1 - k] - latest) / r)
        nodes.append(torch.ones((), device=device))
        neg_h = -h
        phi = torch.expm1(neg_h)  # e^{−h} − 1
        b_h = torch.expm1(neg_h) if self.variant == "bh2" else neg_h
        weights = self._weights(torch.stack(nodes), neg_h, phi, b_h, order, newest is not None, x.dtype)
        out = target / level[0] * x - (1 - target) * phi * latest
        terms = [w * d for w, d in zip(weights, diffs + ([newest - latest] if newest is not None else []))]
        if terms:
            total = terms[0]
            for term in terms[1:]:
                total = total + term
            out = out - (1 - target) * b_h * total
        return out.to(x.dtype)

    @staticmethod
    def _weights(nodes, neg_h, phi, b_h, order: int, corrector: bool, dtype) -> torch.Tensor:
        """ρ of one update (module docstring): (order − 1,) for the predictor, (order,) for the corrector, in
        ``dtype``; nodes: the (order,) float32 r_k, the new prediction's 1 last; neg_h = −h, phi = e^{−h} − 1."""
        half = torch.full((1,), 0.5, dtype=dtype, device=nodes.device)
        if corrector and order == 1:
            return half
        if not corrector and order <= 2:
            return half[: order - 1]
        psi = phi / neg_h - 1
        rows, rhs, factorial = [], [], 1
        for j in range(1, order + 1):
            rows.append(torch.pow(nodes, j - 1))
            rhs.append(psi * factorial / b_h)
            factorial *= j + 1
            psi = psi / neg_h - 1 / factorial
        matrix, vector = torch.stack(rows), torch.stack(rhs)
        if not corrector:
            matrix, vector = matrix[:-1, :-1], vector[:-1]
        return torch.linalg.solve(matrix, vector).to(dtype)


#: scheduler-config settings flow sigmas never read (diffusers' non-flow schedules, thresholding's ratios)
UNREAD_ON_FLOW = frozenset(
    {
        "beta_start",
        "beta_end",
        "beta_schedule",
        "trained_betas",
        "rescale_betas_zero_snr",
        "timestep_spacing",
        "steps_offset",
        "dynamic_thresholding_ratio",
        "sample_max_value",
        "time_shift_type",
        "sigma_min",
        "sigma_max",
    }
)
#: settings that must keep the value given here for the config to run on :class:`FlowUniPC`
FIXED = {
    "use_flow_sigmas": True,
    "prediction_type": "flow_prediction",
    "predict_x0": True,
    "thresholding": False,
    "use_exponential_sigmas": False,
    "use_beta_sigmas": False,
    "use_dynamic_shifting": False,
    "shift_terminal": None,
    "solver_p": None,
}
#: settings :class:`FlowUniPC` reads, with their defaults in diffusers' class
READ = {
    "flow_shift": 1.0,
    "solver_order": 2,
    "solver_type": "bh2",
    "lower_order_final": True,
    "disable_corrector": [],
    "final_sigmas_type": "zero",
    "num_train_timesteps": 1000,
    "use_karras_sigmas": False,  # with sigma_min and sigma_max
}
#: values diffusers' class accepts for unread settings it still checks (else it raises: that path keeps its error)
CHECKED = {
    "beta_schedule": ("linear", "scaled_linear", "squaredcos_cap_v2"),
    "timestep_spacing": ("linspace", "leading", "trailing"),
}


def _is_int(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def solver_for_config(config: Mapping) -> FlowUniPC | None:
    """A :class:`FlowUniPC` with the settings of a diffusers ``UniPCMultistepScheduler`` config (its JSON as a
    dict, ``_``-keys ignored), or None when the config asks for anything this solver does not do (module
    docstring); the caller then builds diffusers' class."""
    cfg = {k: v for k, v in config.items() if not k.startswith("_")}
    if set(cfg) - set(FIXED) - set(READ) - UNREAD_ON_FLOW:
        return None
    for key, wanted in FIXED.items():
        value = cfg.get(key, wanted)
        if bool(value) if wanted is None else value != wanted:  # None: unset or falsy, as diffusers reads it
            return None
    for key, accepted in CHECKED.items():
        if key == "beta_schedule" and cfg.get("trained_betas") is not None:
            continue  # given betas: the schedule's name is not read
        if key in cfg and cfg[key] not in accepted:
            return None
    s = {k: cfg.get(k, default) for k, default in READ.items()}
    karras = None
    if s["use_karras_sigmas"]:
        low, high = cfg.get("sigma_min"), cfg.get("sigma_max")
        numbers = all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in (low, high))
        if not (numbers and 0 < low < high and math.isfinite(high)):
            return None  # diffusers takes a missing bound from its betas
        karras = (float(low), float(high))
    shift, order, steps = s["flow_shift"], s["solver_order"], s["num_train_timesteps"]
    if not (isinstance(shift, (int, float)) and not isinstance(shift, bool) and math.isfinite(shift) and shift > 0):
        return None
    if not (_is_int(order) and order >= 1 and _is_int(steps) and steps >= 1):
        return None
    if s["solver_type"] not in VARIANTS or s["final_sigmas_type"] not in FINAL_SIGMAS:
        return None
    if not isinstance(s["lower_order_final"], bool):
        return None
    skip = s["disable_corrector"]
    if not (isinstance(skip, (list, tuple)) and all(_is_int(i) for i in skip)):
        return None
    return FlowUniPC(
        shift=float(shift),
        order=order,
        variant=s["solver_type"],
        lower_order_final=s["lower_order_final"],
        disable_corrector=skip,
        final_sigma=s["final_sigmas_type"],
        train_steps=steps,
        karras=karras,
    )
