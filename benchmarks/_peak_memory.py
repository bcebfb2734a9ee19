"""Peak memory of a block of code, shared by the benchmarks (``rollout.py``, ``train.py``).

On CUDA: ``torch.cuda.max_memory_allocated`` above the allocated bytes at entry (the peak statistics are reset
at entry). On the CPU: the peak resident set size (``/proc/self/statm``) above the level at entry, sampled every
millisecond by a thread. For clean CPU figures run the process with ``MALLOC_MMAP_THRESHOLD_=65536`` and
``MALLOC_TRIM_THRESHOLD_=0`` so freed tensors leave the process (glibc otherwise keeps them and a later block
reuses them without raising the resident size).
"""

from __future__ import annotations

import os
import threading
import time

__all__ = ["MALLOC_ENV", "PeakMemory"]

#: environment that makes glibc hand freed memory back at once (see the module docstring)
MALLOC_ENV = {"MALLOC_MMAP_THRESHOLD_": "65536", "MALLOC_TRIM_THRESHOLD_": "0"}


def _rss() -> int:
    """Resident set size of this process in bytes."""
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


class PeakMemory:
    """Peak memory (bytes, ``.peak``) above the starting level while the block runs."""

    def __init__(self, device):  # a torch.device; torch is imported by the caller (this module stays torch-free
        # so that a benchmark can read MALLOC_ENV and re-execute itself before importing torch)
        self.device, self.peak, self._stop = device, 0, threading.Event()

    def __enter__(self):
        import torch

        if self.device.type == "cuda":
            torch.cuda.synchronize()
            torch.cuda.reset_peak_memory_stats()
            self.base = torch.cuda.memory_allocated()
        else:
            self.base = self.peak_abs = _rss()
            self._thread = threading.Thread(target=self._sample, daemon=True)
            self._thread.start()
        return self

    def _sample(self):
        while not self._stop.is_set():
            self.peak_abs = max(self.peak_abs, _rss())
            time.sleep(0.001)

    def __exit__(self, *exc):
        import torch

        if self.device.type == "cuda":
            torch.cuda.synchronize()
            self.peak = torch.cuda.max_memory_allocated() - self.base
        else:
            self._stop.set()
            self._thread.join()
            self.peak = max(self.peak_abs, _rss()) - self.base
