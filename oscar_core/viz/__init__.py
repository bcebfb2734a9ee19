"""Looking at episodes in Rerun: ``oscar view`` (docs/viewing.md).

:mod:`.sources` gathers and checks what one episode, clip, rollout or evaluation cell holds;
:mod:`.rerun_log` logs it into a Rerun recording (``.rrd``). Needs the ``viz`` extra
(``pip install "oscar-wm[viz]"``) only to log.
"""

from .rerun_log import capsule_quaternions, log_source, write_recording
from .sources import ViewSource, clip_source, closed_loop_source, describe, episode_source, eval_run_source

__all__ = [
    "ViewSource",
    "episode_source",
    "clip_source",
    "closed_loop_source",
    "eval_run_source",
    "describe",
    "log_source",
    "write_recording",
    "capsule_quaternions",
]
