"""Linear twins: the study's best configuration retried without hidden layers, once per listed trainer method and
learning rate (``[study] linear_twins``).

Why. A net without hidden layers on a short view is the strongest family this engine has measured — the best v2
human net (jnorthrup-v05) is one, and so was every linear net that scored 75 in the benchmark's studies — but the
good linear nets train with another method and rate than the best hidden-layer ones (adagrad at a rate × inputs of
1–10, where gsurma's sgd lineage learns at 0.1), so a sampler that models the method and the rate on every trial
rarely draws them together: over nine hour-long studies, 108 linear adagrad draws, 5 at 74 or more, all at 1–10.
The view, the traffic and the replay settings, in contrast, carry over: the best configuration's are a good guess.
So whenever a configuration with hidden layers (or a linear one with another method or rate) becomes the study's
best — or, with ``[study] linear_twin_span``, comes within that many mph of it — its twins, the same parameters
with ``n_layers = 0`` and each listed (method, rate per input), are enqueued: ordinary trials, each trained once
at its parent's budget, unpruned, that enter the sampler's history (and, being linear, the seed soups). Offline,
gsurma's crowd setting as a linear adagrad net at 10 per input scored 74.20, 73.65, 74.42 at 90k (its own setting
at 90k: 74.0 on average); jnorthrup-v05's view (6 lanes a side, 52 ahead, none behind) as one, at 1, 3 and 10 per
input: 65.8–69.1, 59.9–73.2 and 65.3–72.5, so a crowd linear setting is no better a parent than the best.

Linear neighbours (``[study] linear_neighbours``). A linear configuration's soups rise far above its single nets, and
how far depends on the configuration: in crowd-prior hours the soups of gsurma's view (2 lanes a side, 15 patches ahead,
7 behind, γ 0.9) stopped at 75.35 and 75.57 over 43 and 64 seeds, those of a search trial's linear twin (5 lanes a side,
15 ahead, 9 behind, γ 0.72) reached 75.72 in the hour and 75.80 offline. So once a linear configuration's net (its own
training, or its seed soup) is the study's best net, or it is the linear configuration with the best mean over its fresh
seeds, its neighbours — its parameters with the temporal window dropped, or one of γ (as 1 − γ), the view or the rate
moved one step (``NEIGHBOUR_STEPS``) — are enqueued once, trained like twins; each being linear, it gets probe seeds and
soups, and one whose soups become the best net, or whose seeds' mean leads, gets its neighbours in turn: a climb on the
mean over seeds, the measure the seed race and ``autotune best`` rank configurations by.
Outside a study, 6 seeds each of gsurma's adagrad twin and of its neighbours greedily souped at 74.83 for the
twin and at 75.42 (a lane a side less), 75.25 (γ 0.8), 75.06, 75.02, 74.85, 74.66, 74.52, 74.30, 73.98 for them.

Pure functions of params and trials; ``autotune.search.driver`` enqueues what they return.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import Any

from optuna.trial import FrozenTrial

from autotune.search import keys
from autotune.search.spec import LR_X_INPUTS, Dimension

__all__ = ["NEIGHBOUR_STEPS", "TWIN_SKIP", "neighbours", "parent", "parents", "twins"]

TWIN_SKIP = (keys.RETRY_OF, keys.RACE_OF, keys.REFINE_OF, keys.COPIED_FROM, keys.SOUP_OF, keys.TWIN_OF,
             keys.NEIGHBOUR_OF)  # fmt: skip
"""A trial with one of these user attrs is no parent: a retry, a race, refinement or soup run (their scores are not
their configuration's first measure), copied history, or a twin or neighbour itself (its twins are its siblings)."""

NEIGHBOUR_STEPS: tuple[tuple[str, str, float], ...] = (
    ("temporal_window", "=", 0),
    ("one_minus_gamma", "×", 2.0), ("one_minus_gamma", "×", 0.5),
    ("lanes_side", "+", -1), ("lanes_side", "+", 1),
    ("patches_ahead", "×", 0.75), ("patches_ahead", "×", 4 / 3),
    ("patches_behind", "+", -2), ("patches_behind", "+", 2),
    (LR_X_INPUTS, "×", 0.5), (LR_X_INPUTS, "×", 2.0),
)  # fmt: skip
"""(parameter, × or + or =, step) of each neighbour, in order: no temporal window, 1 − γ doubled and halved, a lane a
side less and more, a quarter of the patches ahead less and a third more, two patches behind less and more, the
rate per input halved and doubled.

The window dropped first: every linear family whose soups passed 75.5 saw one frame or two (windows 0–1), and a windowed
leader never leaves its window by the other steps. In a crowd-prior hour (seed 1, dea790b) 31 of 82 fresh window-0
linear trainings scored 74 or more (the best 75.81); in a cold 30-minute study (seed 0, dea790b) TPE drew no window-0
linear net, and its 43 window-7 ones peaked at 73.78 (soups 74.48); the cold hours that missed 75 had settled on windows
of 4–5 and 9–10 (seeds 2 and 3, 6 Dec). Halving the window instead (f5a308d, not kept) stayed windowed: window 4 scored
below its window-8 parents. Offline, that 30-minute study's window-7 family (trial 64, 270k, seeds 11–14) scored 72.01 a
seed on average with its window and 73.09 without, each training in under half the time. Inside an hour (cold, seed 2,
3065400) it acted three times, one seed each: 70.57, 72.42, 73.11 against its parents' 68.42, 74.23, 72.94, lifting no
family past 74.86. Its rate per input is kept, so its learning rate rises with the inputs it sheds.

1 − γ doubled next: in both linear families measured the shorter horizon won, gsurma's adagrad
twin (γ 0.9) at γ 0.8 75.25 against 73.98 at γ 0.95 (6 seeds each, souped), jnorthrup-v05's view (γ 0.989) at
γ 0.978 75.85 against 62.00 at γ 0.994 (a crowd-prior hour, seed 2; the first's 9 seeds: median 75.72), and the
neighbours start one at a time under ``[study] side_share``, each of that view ~4 minutes."""


def twins(params: Mapping[str, Any], rates: Iterable[tuple[str, Sequence[float]]]) -> list[dict[str, Any]]:
    """``params`` without hidden layers, once per (method, rate per input) of ``rates``, in order; the parameters
    the layout leaves unused (``neurons_i``, ``activation_i``) keep their values. A twin equal to ``params`` is left
    out."""
    out = []
    for method, values in rates:
        for rate in values:
            twin = {**params, "n_layers": 0, "method": method, LR_X_INPUTS: float(rate)}
            if twin != dict(params) and twin not in out:
                out.append(twin)
    return out


def neighbours(params: Mapping[str, Any], space: Sequence[Dimension]) -> list[dict[str, Any]]:
    """``params`` with one parameter moved (or set, ``=``) per ``NEIGHBOUR_STEPS`` entry, in order, inside ``space``
    (clipped to a dimension's range; an integer one moved by × or + rounded but by one at least); a step whose
    parameter is not searched, that leaves ``params`` unchanged (at a bound, or already at its ``=`` value), or that
    repeats an earlier neighbour is left out."""
    dims = {d.name: d for d in space}
    out: list[dict[str, Any]] = []
    for name, op, step in NEIGHBOUR_STEPS:
        d = dims.get(name)
        if d is None or d.kind == "categorical" or name not in params:
            continue
        now = params[name]
        value = now * step if op == "×" else now + step if op == "+" else step
        if d.kind == "int" and op != "=":  # at least one unit: a third more than 1 patch is 2
            value = round(value) if round(value) != now else now + (1 if value > now else -1)
        assert d.low is not None and d.high is not None
        value = min(max(value, d.low), d.high)
        moved = {**params, name: int(value) if d.kind == "int" else float(value)}
        if moved != dict(params) and moved not in out:
            out.append(moved)
    return out


def parent(trials: Sequence[FrozenTrial], score: Callable[[FrozenTrial], float | None]) -> FrozenTrial | None:
    """The trial to twin: the best by ``score`` (None: not a candidate; the driver's is its best net trained at the
    ladder's min_top or above, so a lucky 10k screening draw is no parent) of the study's first measures of
    configurations (``TWIN_SKIP`` left out), the earlier on a tie; None before any."""
    ranked = parents(trials, score, 0.0)
    return ranked[0] if ranked else None


def parents(
    trials: Sequence[FrozenTrial], score: Callable[[FrozenTrial], float | None], span: float
) -> list[FrozenTrial]:
    """The trials to twin, best first: of the study's first measures of configurations (``TWIN_SKIP`` left out) with
    a ``score`` (see ``parent``), the best and those within ``span`` mph of it (``[study] linear_twin_span``), the
    earlier first on a tie; [] before any."""
    scored: list[tuple[float, int, FrozenTrial]] = []
    for t in trials:
        if any(k in t.user_attrs for k in TWIN_SKIP) or "n_layers" not in t.params:
            continue
        s = score(t)
        if s is not None and math.isfinite(s):
            scored.append((s, -t.number, t))
    if not scored:
        return []
    scored.sort(key=lambda r: r[:2], reverse=True)
    top = scored[0][0]
    return [t for s, _, t in scored if s >= top - span]
