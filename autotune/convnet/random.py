"""convnetjs's random routines as the original draws them from ``Math.random`` (mulberry32).

``gaussRandom`` is Marsaglia's polar method with a **global** one-value cache: every ``new Vol``
draws its Gaussians through it, so building a brain (its weights) and every forward pass of
deepqlearn (``new Vol(1, 1, n)``, whose values are overwritten) advance the stream. Here only
the draw count and the cache flag are reproduced where the values are never needed.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from autotune.convnet.spec import ConvNet
from sim.rng import mrand

__all__ = ["build_draws", "build_gaussians", "gauss_skip", "replay_build"]


@njit(cache=True, error_model="numpy", inline="always")
def gauss_skip(mr: np.ndarray, w: int, cache: int, n: int) -> int:
    """Consume the ``Math.random`` draws of ``n`` ``gaussRandom()`` calls; returns the new cache flag.

    The values are never needed (the Vol is overwritten), only the draw count and the cache.
    """
    if n <= 0:
        return cache
    m = n - 1 if cache != 0 else n  # values still needed after using a cached one
    for _ in range((m + 1) // 2):
        while True:
            u = 2.0 * mrand(mr, w) - 1.0
            v = 2.0 * mrand(mr, w) - 1.0
            r = u * u + v * v
            if r == 0.0 or r > 1.0:
                continue
            break
    return 1 if m % 2 == 1 else 0


@njit(cache=True, error_model="numpy")
def replay_build(state: int, cache: int, n_gauss: int) -> tuple[int, int, int]:
    """Replay ``n_gauss`` Gaussian draws from mulberry32 ``state``: (new state, cache flag, uniform draws)."""
    mr = np.zeros(1, dtype=np.int64)
    mr[0] = state
    draws = 0
    c = cache
    if n_gauss > 0:
        m = n_gauss - 1 if c != 0 else n_gauss
        for _ in range((m + 1) // 2):
            while True:
                u = 2.0 * mrand(mr, 0) - 1.0
                v = 2.0 * mrand(mr, 0) - 1.0
                draws += 2
                r = u * u + v * v
                if r == 0.0 or r > 1.0:
                    continue
                break
        c = 1 if m % 2 == 1 else 0
    return mr[0], c, draws


def build_gaussians(net: ConvNet) -> int:
    """Gaussians drawn by ``new deepqlearn.Brain`` for this architecture: ``Σ in·out`` over fc layers."""
    return int(sum(w.size for w, _b in net.params))


def build_draws(net: ConvNet, seed: int, cache: int = 0) -> tuple[int, int, int]:
    """(mulberry32 state after the brain build, Gaussian cache flag, number of ``Math.random`` draws)."""
    s, c, n = replay_build(int(seed) & 0xFFFFFFFF, cache, build_gaussians(net))
    return int(s), int(c), int(n)
