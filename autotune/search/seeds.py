"""The study's derived seeds: a trial's, a reseeded rung's and a seed race run's, from one recipe.

Each is a pure function of integers the study stores (its seed, a trial number, a salt, a budget or a race
index), so a resumed or retried run trains from the same seed, and different uses never share one.
"""

from __future__ import annotations

import numpy as np

__all__ = ["derived_seed"]


def derived_seed(*parts: int) -> int:
    """A training seed in [0, 2³¹) drawn from ``parts`` by NumPy's ``SeedSequence``: independent for different
    parts, the same for the same ones."""
    return int(np.random.SeedSequence([int(p) for p in parts]).generate_state(1, np.uint32)[0] >> 1)
