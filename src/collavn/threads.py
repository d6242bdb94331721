"""How many threads a process runs: torch (intra- and inter-op) and Numba.

Two training runs on a 2-core machine used to go ~15× slower each instead of ~2×: every
process ran as many torch/OpenMP threads as there are cores, and workers spinning at
OpenMP barriers fought the other process's threads (and the renderer's) for the same
cores. The models here are small and their batches short (tens of agents), so
intra-op parallelism gains little even alone (measured in ``benchmarks/train.py``).
Automatic (``0``) is therefore **one torch thread, one inter-op thread and one Numba
thread per process**; the renderer has its own setting (``EnvConfig.render_threads``,
1 in the ``cpu`` preset). Use more processes (``torchrun``) for more cores, or ask for
threads explicitly (``--torch-threads``) for a big encoder alone on a machine.
"""

from __future__ import annotations


def resolve_threads(requested: int) -> int:
    """The torch thread count for a request (``0`` = automatic = 1)."""
    if requested < 0:
        raise ValueError(f"thread count must be ≥ 0, got {requested}")
    return requested or 1


def apply_threads(requested: int) -> int:
    """Set Numba's and torch's thread counts for this process; returns the torch count.

    Numba first: its OpenMP threading layer starts by setting the OpenMP thread count
    of the calling thread to all cores, which torch reads as its own intra-op count —
    set after torch, it silently put a one-thread run back on two threads whenever
    torch had already run an op (and made a resumed run round differently from an
    uninterrupted one).
    """
    import torch

    n = resolve_threads(requested)
    try:
        import numba

        numba.set_num_threads(min(n, numba.config.NUMBA_NUM_THREADS))  # type: ignore[attr-defined]
    except ImportError:  # pragma: no cover - numba is a dependency of the renderer
        pass
    torch.set_num_threads(n)
    try:
        torch.set_num_interop_threads(1)
    except RuntimeError:  # only settable before the first inter-op work; keep it then
        pass
    return n
