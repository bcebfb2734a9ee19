"""Evaluation metrics: policy-evaluation fidelity and video quality.

* :mod:`oscar_core.metrics.policy` — MMRV (SIMPLER's and the paper's rank
  form), Spearman ρ, Pearson r, SISR_Δ, and Bradley–Terry–Davidson scores.
* :mod:`oscar_core.metrics.video` — PSNR, SSIM, LPIPS, tLPIPS, latent L2,
  Fréchet distances (FVD / FID) with user-supplied networks.
* :mod:`oscar_core.metrics.judge` — VLM judges of rollouts through any
  OpenAI-compatible endpoint: per-clip success and pairwise preferences.
* :mod:`oscar_core.metrics.programmatic` — judges that are functions of the video.
* :mod:`oscar_core.metrics.weights` — ``oscar eval weights pull``: the standard
  I3D / Inception / LPIPS files, pinned and hash-checked, in a cache;
  :mod:`oscar_core.metrics.lpips_net` — LPIPS without torchvision;
  :mod:`oscar_core.metrics.project_vae` — latent L2 with the project's VAE.
* :mod:`oscar_core.metrics.plots` — success-rate scatter and rank slope chart
  (matplotlib, optional).
* :mod:`oscar_core.metrics.cli` — the ``oscar eval`` sub-commands.

Names are re-exported here flat; submodules load on first use, so importing
this package does not import torch.
"""

from __future__ import annotations

from .._util.lazy import lazy_exports

_EXPORTS = {
    "MetricInputError": "common",
    # policy evaluation
    "mmrv_simpler": "policy",
    "mmrv_rank": "policy",
    "mmrv_rank_max": "policy",
    "spearman_rho": "policy",
    "pearson_r": "policy",
    "sisr_delta": "policy",
    "average_ranks": "policy",
    "success_rates": "policy",
    "PolicyComparison": "policy",
    "compare_policies": "policy",
    "Preference": "policy",
    "parse_preference": "policy",
    "BradleyTerryResult": "policy",
    "BradleyTerryWarning": "policy",
    "fit_bradley_terry": "policy",
    # video quality
    "psnr": "video",
    "ssim": "video",
    "lpips": "video",
    "tlpips": "video",
    "latent_l2": "video",
    "feature_statistics": "video",
    "frechet_distance": "video",
    "frechet_distance_from_features": "video",
    "fvd": "video",
    "fid": "video",
    "video_features": "video",
    "frame_features": "video",
    "load_torchscript": "video",
    "Clip": "video",
    "VideoReport": "video",
    "evaluate_videos": "video",
    "DEFAULT_FRAMES": "video",
    "load_video": "video",
    # VLM judges
    "JudgeClip": "judge",
    "JudgePair": "judge",
    "SuccessJudge": "judge",
    "PairwiseJudge": "judge",
    "SuccessVerdict": "judge",
    "PairwiseVerdict": "judge",
    "ChatClient": "judge",
    "MalformedAnswer": "judge",
    "JudgeRequestError": "judge",
    "JudgeEndpointUnreachable": "judge",
    "parse_success_answer": "judge",
    "parse_pairwise_answer": "judge",
    "sample_frame_indices": "judge",
    "pairs_by_session": "judge",
    "success_by_policy": "judge",
    "preferences_from_verdicts": "judge",
    "PAPER_SUCCESS_PROMPT": "judge",
    "SUCCESS_SYSTEM_PROMPT": "judge",
    "SUCCESS_USER_PROMPT": "judge",
    "PAIRWISE_SYSTEM_PROMPT": "judge",
    "PAIRWISE_USER_PROMPT": "judge",
    "ProgrammaticJudge": "programmatic",
    "check_verdict_fields": "programmatic",
    # standard networks
    "LPIPS": "lpips_net",
    "WEIGHTS": "weights",
    "WeightFile": "weights",
    "WeightHashError": "weights",
    "pull_weights": "weights",
    "weight_path": "weights",
    "cached_networks": "weights",
    "load_project_vae": "project_vae",
    # plots
    "success_scatter_figure": "plots",
    "rank_slope_figure": "plots",
    "save_figure": "plots",
    "plot_success_scatter": "plots",
    "plot_rank_slope": "plots",
    "plot_comparison": "plots",
    # CLI glue
    "add_eval_parser": "cli",
}

__all__, __getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
