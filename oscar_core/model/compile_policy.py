"""When and how the DiT is compiled: one policy for ``oscar rollout``, ``oscar eval run`` and the Python API.

``torch.compile`` pays for itself only over enough work: compiling the 2B DiT
costs about a minute, and each 35-step chunk then runs about 6 s faster. So:

* ``never`` — eager; ``always`` — compile (on any device; the user asked);
* ``auto`` (the default) — compile on CUDA only, and only when the job's
  expected saving beats the compile cost: ``chunks × (EAGER_CHUNK_S −
  COMPILED_CHUNK_S) × evaluations / 70 > COMPILE_COST_S``, where ``chunks`` counts
  every chunk the process will sample (chunks per rollout × cells). With the
  numbers below that is 11 chunks or more at 35 steps (a one-chunk
  ``oscar rollout`` stays eager). The saving scales with the DiT
  evaluations a chunk makes (``sampler.model_calls``: 70 at 35 guided steps),
  so the ``fast`` preset (12 steps, 17 evaluations) needs 45 chunks.

The numbers were measured on one H200 by issue 23 (81 frames, 512x288,
35 UniPC steps, guidance w = 6, bf16): one chunk eager 17.6 s, compiled
11.8 s; a one-chunk ``oscar rollout`` took 39 s eager and 96 s with
``--compile``, so a cold compile costs 96 − 39 + (17.6 − 11.8) ≈ 63 s. A warm
persistent cache (:func:`configure_compile_cache`) makes later compiles
cheaper; how much was not measured on a GPU, so ``auto`` keeps the cold cost.

The DiT is compiled once per process: :func:`compile_transformer` keeps the
compiled forward on the module and a second call (a second chunk, rollout
or evaluation cell) reuses it without calling ``torch.compile`` again. Shapes
are static (``dynamic=False``): every chunk of a rollout has the same shape
(the last one's condition video is padded), so one graph serves them all.
If compiling fails (no C++ compiler, no Triton, an unsupported Python), one
warning names the reason and the model runs eager from then on.
"""

from __future__ import annotations

import math
import os
import weakref
from pathlib import Path

from .._util.log import get_logger
from .errors import ModelInputError

__all__ = [
    "COMPILED_CHUNK_S",
    "COMPILE_COST_S",
    "COMPILE_MODES",
    "EAGER_CHUNK_S",
    "PAPER_STEPS",
    "add_compile_options",
    "break_even_chunks",
    "check_compile_mode",
    "compile_decision",
    "compile_transformer",
    "configure_compile_cache",
    "default_compile_cache_dir",
    "is_compiled",
]

_log = get_logger(__name__)

COMPILE_MODES = ("auto", "always", "never")
#: seconds per 35-step chunk of the 2B DiT on one H200, eager and compiled (measured by issue 23)
EAGER_CHUNK_S = 17.6
COMPILED_CHUNK_S = 11.8
#: seconds a cold compile adds (issue 23's one-chunk CLI: 96 s compiled − 39 s eager + the 5.8 s that chunk saved)
COMPILE_COST_S = 96.0 - 39.0 + (EAGER_CHUNK_S - COMPILED_CHUNK_S)
PAPER_STEPS = 35

_compiled: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()  # transformer -> _CompiledForward


def check_compile_mode(mode) -> str:
    """``mode`` if it is one of :data:`COMPILE_MODES`, else a ModelInputError naming what was found."""
    if mode not in COMPILE_MODES:
        raise ModelInputError(f"compile: expected one of {COMPILE_MODES}, found {mode!r}")
    return mode


def break_even_chunks(steps: int = PAPER_STEPS, evaluations: int | None = None) -> int:
    """The fewest chunks whose saving exceeds :data:`COMPILE_COST_S`.

    The saving per chunk scales with the DiT's work: ``evaluations`` DiT evaluations (batch items) per chunk,
    ``oscar_core.model.sampler.model_calls``; None: ``2 × steps`` (guidance at every step, as measured).
    """
    evaluations = 2 * steps if evaluations is None else evaluations
    saving = (EAGER_CHUNK_S - COMPILED_CHUNK_S) * evaluations / (2 * PAPER_STEPS)
    return math.floor(COMPILE_COST_S / saving) + 1


def compile_decision(
    mode: str, device, chunks: int, steps: int = PAPER_STEPS, evaluations: int | None = None
) -> tuple[bool, str]:
    """(compile?, why) for a job of ``chunks`` chunks of ``steps`` steps (``evaluations`` DiT evaluations each,
    None: 2 × steps) on ``device`` (module docstring)."""
    check_compile_mode(mode)
    if mode == "never":
        return False, "compile=never"
    if mode == "always":
        return True, "compile=always"
    if not str(device).startswith("cuda"):
        return False, f"compile=auto: eager on {device} (compiling pays off on CUDA only)"
    need = break_even_chunks(steps, evaluations)
    work = f"{chunks} chunk(s) of {steps} steps" + (f" ({evaluations} DiT evaluations each)" if evaluations else "")
    if chunks >= need:
        return True, f"compile=auto: {work} >= {need}, where compiling pays for itself"
    return False, f"compile=auto: {work} < {need}; eager is faster end to end (--compile always to force)"


class _CompiledForward:
    """The transformer's forward, compiled; on a compiler failure, eager for good (one warning)."""

    def __init__(self, module, eager, compiled):
        self._module = weakref.ref(module)
        self.eager, self.compiled, self.failed = eager, compiled, None

    def __call__(self, *args, **kwargs):
        if self.failed is not None:
            return self.eager(*args, **kwargs)
        try:
            return self.compiled(*args, **kwargs)
        except Exception as exc:  # noqa: BLE001 - any compiler fault; the eager call below re-raises input errors
            out = self.eager(*args, **kwargs)  # an error of the inputs themselves raises here, as eager would
            self._fall_back(
                f"{type(exc).__name__}: {str(exc).strip().splitlines()[0][:300] if str(exc).strip() else ''}"
            )
            return out

    def _fall_back(self, reason: str) -> None:
        self.failed = reason
        _log.warning("torch.compile of the DiT failed (%s); running eager", reason)
        module = self._module()
        if module is not None and module.__dict__.get("forward") is self:
            del module.forward


def compile_transformer(transformer, *, mode: str | None = None) -> bool:
    """Compile ``transformer.forward`` once per process (later calls reuse it); True when it runs compiled.

    mode: ``torch.compile``'s mode (None: its default). Shapes static. On a failure to compile (at wrapping or
    at the first call) a warning names the reason and the transformer stays eager.
    """
    import torch

    state = _compiled.get(transformer)
    if state is not None:
        return state.failed is None
    configure_compile_cache()
    eager = transformer.forward
    try:
        compiled = torch.compile(eager, dynamic=False, mode=mode)
    except Exception as exc:  # noqa: BLE001 - e.g. "not supported on Python 3.x", a missing backend
        state = _CompiledForward(transformer, eager, None)
        _compiled[transformer] = state
        state._fall_back(f"{type(exc).__name__}: {exc}")
        return False
    state = _CompiledForward(transformer, eager, compiled)
    _compiled[transformer] = state
    transformer.forward = state
    return True


def is_compiled(transformer) -> bool:
    """Whether ``transformer`` currently runs a compiled forward (False after a fallback)."""
    state = _compiled.get(transformer)
    return state is not None and state.failed is None


def default_compile_cache_dir() -> Path:
    """``$OSCAR_CACHE/compile``, else ``$XDG_CACHE_HOME/oscar/compile`` (``~/.cache/oscar/compile``)."""
    root = os.environ.get("OSCAR_CACHE")
    if root:
        return Path(root) / "compile"
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "oscar" / "compile"


def configure_compile_cache() -> str:
    """Point inductor's on-disk caches at a persistent per-user folder unless the user chose one; returns it.

    Inductor keeps its FX-graph, autotuning and Triton caches under ``$TORCHINDUCTOR_CACHE_DIR``, by default in
    ``/tmp/torchinductor_$USER`` (lost at reboot). An unset variable is set to :func:`default_compile_cache_dir`;
    a set one is left alone. The FX-graph cache itself is on by default in torch ≥ 2.4 and is left as configured.

    torch sets the variable itself, to its ``/tmp`` default, the first time anything asks for the cache folder —
    importing diffusers does — so a value equal to torch's default counts as unset (before this, the CLI's
    compiles went to ``/tmp`` and ``$OSCAR_CACHE/compile`` stayed empty; benchmarks/cli_rollout.py found it).
    """
    chosen = os.environ.get("TORCHINDUCTOR_CACHE_DIR")
    if chosen and os.path.abspath(chosen) != _torch_default_cache_dir():
        return chosen
    path = default_compile_cache_dir()
    os.environ["TORCHINDUCTOR_CACHE_DIR"] = str(path)
    return str(path)


def _torch_default_cache_dir() -> str | None:
    """The folder inductor uses when ``TORCHINDUCTOR_CACHE_DIR`` is unset (``/tmp/torchinductor_$USER``)."""
    try:
        from torch._inductor.runtime.cache_dir_utils import default_cache_dir
    except ImportError:  # another torch layout: nothing to compare with
        return None
    return os.path.abspath(default_cache_dir())


def add_compile_options(parser) -> None:
    """``--compile auto|always|never`` (a bare ``--compile``: always) and ``--no-compile`` (= never) on an
    ``argparse`` parser; the value lands in ``args.compile`` (default ``auto``)."""
    group = parser.add_mutually_exclusive_group()
    group.add_argument(
        "--compile",
        choices=COMPILE_MODES,
        nargs="?",
        const="always",
        default="auto",
        help=f"torch.compile the DiT: auto (default: on CUDA when the job has >= {break_even_chunks()} "
        "35-step chunks, where compiling pays for itself), always, never (docs/world-model.md)",
    )
    group.add_argument(
        "--no-compile",
        dest="compile",
        action="store_const",
        const="never",
        help="run the DiT eager (= --compile never)",
    )
