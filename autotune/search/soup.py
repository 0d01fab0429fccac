"""Weight soups: the uniform average of the weights of a parent's best refinement runs, scored as a net of its own.

Refinement runs of one parent (``autotune.search.refine``) all start from the same weights and train a few
thousand steps each, so they stay in one basin of the loss; averaging such fine-tuned nets ("model soups",
Wortsman et al., 2022) often scores above every one of them, for the price of one official evaluation and no
training. Measured on gsurma's setting outside a study (8 runs a step, 20k iterations at a tenth of its rate; the
step's best net — run or soup — the next parent): the soup of the best 2 or 4 runs beat the best run in 4 of the
first 5 steps (75.15 against 75.02, 75.28 / 75.15, 75.31 / 75.20, 75.45 / 75.42), and the soups' own runs climbed
from them; the soup of all 8 (the bad runs too) never did.

When a worker would start a refinement run of a parent whose best ``k`` runs (``[study] refine_soups`` = the sizes
k) form a set no soup of it has tried yet, it scores that set's soup instead (``next_soup``). Only runs within
``SOUP_SPAN`` of their parent's score are ingredients: in a crowd-prior study the best 4 of a parent's first runs
included two that had collapsed (69.08, 56.12), and their soup scored 73.37 against the parent's 75.29; every soup
that won outside a study had its ingredients within 0.4 mph of the parent. A soup is an ordinary
trial: ``refine_of`` its parent, ``soup_of`` its ingredients (the trials whose nets it averages; its net reproduces
from theirs), its config theirs. A soup that beats its parent is a parent like any run that did. Independent
trainings average only without hidden layers: ``autotune.search.ensemble``'s seed soups.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

import numpy as np

from autotune.convnet.spec import ConvNet, NetSpecError, same_structure

__all__ = ["SOUP_SPAN", "average_nets", "next_soup"]

SOUP_SPAN = 0.5
"""mph below its parent's score within which a refinement run is a soup ingredient."""


def average_nets(nets: Sequence[ConvNet]) -> ConvNet:
    """The net whose every weight and bias is the mean of ``nets``' (one structure, ≥ 1 net)."""
    if not nets:
        raise NetSpecError("a weight soup needs at least one net")
    first = nets[0]
    for k, net in enumerate(nets[1:], 1):
        if not same_structure(net.layers, first.layers):
            raise NetSpecError(f"soup ingredient {k}: its layers differ from ingredient 0's; a soup averages one "
                               "structure's weights")  # fmt: skip
    params = tuple(
        (np.mean([n.params[i][0] for n in nets], axis=0), np.mean([n.params[i][1] for n in nets], axis=0))
        for i in range(len(first.params))
    )
    return ConvNet(first.layers, params)


def next_soup(
    runs: Iterable[tuple[int, float]], sizes: Sequence[int], tried: Iterable[Iterable[int]], floor: float = -math.inf
) -> tuple[int, ...] | None:
    """The ingredients (trial numbers, ascending) of the next soup of one parent: for each size k of ``sizes`` in
    order, its best k finished ``runs`` (trial number, score; best score first, the earlier trial on ties) that
    score ``floor`` or more (the parent's score − ``SOUP_SPAN``), when there are k of them and no soup in ``tried``
    (each an ingredient set) had that set; None when every size's set was tried (or too few runs qualify)."""
    ranked = sorted((r for r in runs if r[1] >= floor), key=lambda r: (-r[1], r[0]))
    seen = {frozenset(s) for s in tried}
    for k in sizes:
        if len(ranked) < k:
            continue
        best = frozenset(n for n, _ in ranked[:k])
        if best not in seen:
            return tuple(sorted(best))
    return None
