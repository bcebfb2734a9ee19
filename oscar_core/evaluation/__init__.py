"""The policy-evaluation loop: ``oscar eval run MANIFEST``.

* :mod:`oscar_core.evaluation.manifest` — the manifest (sessions × policies) and its checks.
* :mod:`oscar_core.evaluation.loop` — rollouts (resumable), verdicts, preferences.
* :mod:`oscar_core.evaluation.report` — ``report.json``, ``summary.md``, plots, contact sheets.
* :mod:`oscar_core.evaluation.roboarena` — a RoboArena evaluation dump → a manifest and the real results.
* :mod:`oscar_core.evaluation.cli` — the ``oscar eval run`` sub-command.

Names are re-exported flat; submodules load on first use (no torch at import).
"""

from __future__ import annotations

from .._util.lazy import lazy_exports

_EXPORTS = {
    "Cell": "manifest",
    "Manifest": "manifest",
    "ManifestError": "manifest",
    "load_manifest": "manifest",
    "EvaluationResult": "loop",
    "run_evaluation": "loop",
    "build_report": "report",
    "write_report": "report",
    "contact_sheet": "report",
    "format_summary": "report",
    "load_judge": "cli",
    "convert_roboarena": "roboarena",
    "RoboArenaError": "roboarena",
    "RoboArenaResult": "roboarena",
}

__all__, __getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
