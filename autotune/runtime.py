"""Process-wide settings, set once by whoever owns the process (the CLI's ``main``, a Ray worker).

torch's intra-op threads, denormal flushing and numba's thread count belong to the process, not to
one call: a trial running inside a worker with 2 CPUs must not have ``train`` reset them per call.
"""

from __future__ import annotations

__all__ = ["configure_process", "process_configured"]

_CONFIGURED: dict[str, int | None] = {}


def configure_process(threads: int = 1, *, numba_threads: int | None = None, flush_denormal: bool = True) -> None:
    """Set torch's threads (``threads``), denormal flushing and numba's threads for this process.

    ``numba_threads`` None leaves numba's parallel loops at their current count (all cores in a
    fresh process; the custom protocol's ``threads`` argument still sets it per evaluation).
    Denormal flushing keeps tiny float32 activations off the slow path; float64 evaluation is
    unaffected in practice (its values never come near 1e-308). Calling it again re-applies.
    """
    import torch

    if threads < 1:
        raise ValueError(f"threads: must be ≥ 1, got {threads}")
    torch.set_num_threads(threads)
    torch.set_flush_denormal(flush_denormal)
    if numba_threads is not None:
        import numba

        numba.set_num_threads(max(1, min(numba_threads, numba.config.NUMBA_NUM_THREADS)))
    _CONFIGURED.update(threads=threads, numba_threads=numba_threads)


def process_configured() -> bool:
    """True once ``configure_process`` ran in this process (``train`` then leaves the settings alone)."""
    return bool(_CONFIGURED)
