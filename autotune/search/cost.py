"""What a rung will cost: a wall-time model of training + official scoring, fitted online to the study.

A uniform draw from the paper's space can train for hours (7 layers × 2,600 wide at batch 400), so
the search must know a draw's price before it pays it. One rung's wall time is modelled as a sum of
non-negative work terms whose coefficients are seconds per unit of work:

* training, per decision: the simulator step (∝ 1 + other_agents: every car moves), the input window
  and the greedy forward pass (∝ inputs, ∝ params), and once learning started one batch update
  (∝ params × batch: the s₀ and s₁ halves through the net, then the backward pass), and the batch's input rows
  gathered from the replay memory (∝ batch × inputs: for a linear net as large as the update itself, so a linear
  net on the whole road was priced at 125–180 s for the 222–289 s its 810k training took without it);
* the official evaluation: a fixed part, one forward pass per decision of every red car
  (∝ (1 + other_agents) and ∝ params × (1 + other_agents)), and per greedy decision the input ``Vol``
  convnetjs allocates, whose Gaussian fill the exact evaluation replays draw for draw
  (∝ (1 + other_agents) × (1 − epsilon_test_time) × inputs: a wide view costs more than a wide net);
  with ``[ladder] epsilon_test_grid`` each grid value's screen adds its share of those runs (the halving screens
  some values on fewer runs than others), less the chosen screen's, which the official evaluation carries on from.

``CostModel.prior()`` holds coefficients measured on the 2-core reference machine (see
``PRIOR``); ``fit`` refits them by non-negative least squares on *relative* errors over the study's
finished rungs, the prior entering as a few pseudo-observations so that a handful of rungs nudges
rather than replaces it. Plain numpy/scipy: no Optuna, no torch, so the driver can price a draw
without building a net.
"""

from __future__ import annotations

import dataclasses
import math
import os
from collections.abc import Iterable, Sequence

import numpy as np

from autotune import TrainConfig

__all__ = ["FEATURES", "PRIOR", "CostModel", "features", "Observation", "rung_memory_bytes", "default_memory_cap"]

FEATURES = (
    "decisions",  # B: simulator step + bookkeeping of the ego
    "car_decisions",  # B·(1+K): every car moves each decision interval
    "input_decisions",  # B·inputs: building the input window
    "forward_work",  # B·params: the greedy forward pass
    "update_work",  # (B − start)·params·batch: the batch update
    "gather_work",  # (B − start)·batch·inputs: the batch's input rows gathered from the replay memory
    "eval_fixed",  # 1 per rung: the official evaluation's set-up (engine, brain build)
    "eval_cars",  # 1+K: cars simulated by the official runs
    "eval_forward",  # params·(1+K): one forward per red car per decision of the official runs
    "eval_inputs",  # (1+K)·(1−ε_test)·inputs: the Gaussian fill of each greedy decision's input Vol
)
"""The model's work terms, in the order of its coefficients."""

PRIOR = np.array([
    6.32e-5,  # s per decision (the learn call and the simulator step of the ego)
    3.86e-7,  # s per car-decision
    2.04e-8,  # s per input per decision
    6.39e-10,  # s per weight per decision (greedy forward, numpy views)
    1.09e-10,  # s per weight × batch sample per update (2B-row forward + backward, torch)
    1.72e-9,  # s per input × batch sample per update (the replay rows gathered into the batch)
    0.764,  # s per official evaluation (engine + brain build, 500 runs of 2,000 frames)
    0.00631,  # s per red car of the official runs
    2.66e-6,  # s per weight per red car (~33,500 float64 forward passes per car)
    2.57e-4,  # s per input per red car at ε_test 0 (the Gaussian fill of ~33,500 input Vols per car)
])  # fmt: skip
"""Prior coefficients [s per unit of each FEATURES term]: the relative least-squares fit (non-negative) to the
2,094 rungs of the search-quality studies of 25 Nov 2026 (paper.toml and quick.toml, cold and with the crowd
prior, 2 workers on the 2-core reference machine, load about 2): median error 11.7 % (90th percentile 34 %) on
those rungs. Without the ``eval_inputs`` term the best fit was off by a median 16.4 % (90th percentile 47 %) —
the official evaluation's own time, by 23 % against 8 % — and the earlier 8-term prior, fitted to 28 rungs, by
a median 94 % (over-predicting). ``gather_work``'s coefficient is the same kind of fit, all ten terms, to the rungs
of ten search-quality hours of 6–7 Dec 2026 (paper.toml, cold and with the crowd prior); the other nine keep their
values. Replayed online over those hours (each trial priced by the fit to the rungs finished before it started),
it cut the median error of the four crowd-prior hours with crowd twins, whose trials are mostly linear nets on the
whole road, from 26–36 % to 4–8 %, and of the other six (cold, or without crowd twins) from 9–13 % to 4–13 %."""

_PRIOR_WEIGHT = 4.0
"""The prior counts as this many observations (spread over its anchor configurations)."""


def features(
    config: TrainConfig,
    *,
    evaluated: bool = True,
    screen: Sequence[float] = (),
    screen_share: float | Sequence[float] = 0.0,
    carried: float | None = None,
) -> np.ndarray:
    """The work terms of one rung of ``config`` (at its ``train_iterations``), see ``FEATURES``.

    ``screen``: the ε_test values its net was screened at before the official evaluation (``[ladder]
    epsilon_test_grid``); ``screen_share``: the share of the protocol's runs each screen ran (one number for
    all, or one per value: the halving stops some early): that share of the runs' cars, forward passes and (at
    its ε) input fills. The screens share the evaluation's set-up, and the chosen one, which ran ``carried`` of
    the runs (default: the largest share), is carried on into the official evaluation (``screen_epsilons``),
    which so runs only the rest of the protocol's runs."""
    b = float(config.train_iterations)
    cars = 1.0 + config.other_agents
    p = float(config.param_count)
    learning = max(0.0, b - config.start_learn_threshold)
    ev = 1.0 if evaluated else 0.0
    k = len(screen) if evaluated else 0
    shares = [float(screen_share)] * k if isinstance(screen_share, (int, float)) else [float(x) for x in screen_share]
    if k and len(shares) != k:
        raise ValueError(f"screen_share: {len(shares)} shares for {k} screened values")
    done = (max(shares) if carried is None else float(carried)) if k else 0.0
    rest = ev * (1.0 - done)  # the official runs after the chosen screen's
    runs = rest + (sum(shares) if k else 0.0)  # official evaluations' worth of runs
    screened = sum(x * (1.0 - e) for x, e in zip(shares, screen, strict=True)) if k else 0.0  # their greedy runs
    greedy = rest * (1.0 - config.epsilon_test_time) + screened
    batch = learning * config.batch_size
    return np.array([b, b * cars, b * config.net_inputs, b * p, batch * p, batch * config.net_inputs,
                     ev, runs * cars, runs * p * cars, cars * greedy * config.net_inputs])  # fmt: skip


WEIGHT_COPIES = 8
"""Copies of the net's parameters a training holds, counted generously: torch's weights and gradients, the trainer's
state (adadelta keeps two), the float64 forward copy and the batch buffers."""


def rung_memory_bytes(config: TrainConfig) -> int:
    """Memory one rung of ``config`` allocates beyond the worker's own: the replay memory (``replay_bytes``: the
    rows its schedule can fill) and ``WEIGHT_COPIES`` float64 copies of the net. A rung's memory is not priced in
    seconds — a draw the machine cannot hold is refused whatever its time (``[study] max_trial_memory_gb``)."""
    return int(config.replay_bytes + WEIGHT_COPIES * 8 * config.param_count)


def default_memory_cap(workers: int, share: float = 0.6) -> int:
    """Bytes a rung may use when the spec sets no cap: ``share`` of this machine's memory, split among the
    ``workers`` that train side by side (the rest: the workers' own ~1–2 GB each, the driver, Ray, the OS)."""
    try:
        total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (AttributeError, OSError, ValueError):  # pragma: no cover - not a POSIX system
        total = 16 * 2**30
    return int(share * total / max(1, workers))


@dataclasses.dataclass(frozen=True)
class Observation:
    """A finished rung: its config's work terms and the wall seconds it took."""

    features: tuple[float, ...]
    seconds: float


@dataclasses.dataclass(frozen=True)
class CostModel:
    """Coefficients [s per unit of work] of ``FEATURES``; predicts a rung's wall seconds."""

    coef: tuple[float, ...] = tuple(PRIOR.tolist())
    n_observations: int = 0
    """Finished rungs the coefficients were fitted to (0: the prior alone)."""
    screen: tuple[float, ...] = ()
    """The study's ``[ladder] epsilon_test_grid``: every predicted rung screens its net at these ε_test values
    (unless ``predict(..., screened=False)``: a race run is scored at its configuration's own ε_test)."""
    screen_share: float = 0.0
    """The share of the official protocol's runs a screen evaluates, on average over the grid's values."""
    screen_carried: float = 0.0
    """The share the chosen screen ran (the halving's last stage), carried on into the official evaluation; 0:
    ``screen_share`` (one stage)."""

    def __post_init__(self) -> None:
        if len(self.coef) != len(FEATURES):
            raise ValueError(f"CostModel: {len(self.coef)} coefficients for the {len(FEATURES)} work terms of "
                             f"FEATURES ({', '.join(FEATURES)}); give one per term")  # fmt: skip

    @classmethod
    def prior(cls) -> CostModel:
        return cls()

    def predict_features(self, x: np.ndarray) -> float:
        return float(np.dot(np.asarray(self.coef), x))

    def predict(self, config: TrainConfig, *, evaluated: bool = True, screened: bool = True) -> float:
        """Predicted wall seconds of training ``config`` at its ``train_iterations`` (+ its official score, and the
        ε_test screens of ``screen`` unless ``screened`` is False)."""
        screen = self.screen if screened else ()
        return self.predict_features(features(config, evaluated=evaluated, screen=screen,
                                              screen_share=self.screen_share,
                                              carried=self.screen_carried or None))  # fmt: skip

    def screening(self, grid: Sequence[float], share: float, carried: float = 0.0) -> CostModel:
        """This model predicting rungs whose nets are screened at ``grid`` on ``share`` of the runs each (on
        average), the chosen one on ``carried`` (0: ``share``)."""
        return dataclasses.replace(self, screen=tuple(float(e) for e in grid), screen_share=float(share),
                                   screen_carried=float(carried))  # fmt: skip

    def fit(self, observations: Iterable[Observation]) -> CostModel:
        """Refit to finished rungs (relative least squares, non-negative), the prior as pseudo-observations."""
        from scipy.optimize import nnls

        obs = [o for o in observations if o.seconds > 0 and math.isfinite(o.seconds)]
        if not obs:
            return dataclasses.replace(self, coef=tuple(PRIOR.tolist()), n_observations=0)
        prior = np.asarray(PRIOR)
        rows: list[np.ndarray] = []
        target: list[float] = []
        for o in obs:
            x = np.asarray(o.features, dtype=float)
            rows.append(x / o.seconds)
            target.append(1.0)
        # the prior: each coefficient pulled toward its prior value, scaled to a relative residual
        w = math.sqrt(_PRIOR_WEIGHT / len(prior))
        for j, c in enumerate(prior):
            e = np.zeros(len(prior))
            e[j] = w / c
            rows.append(e)
            target.append(w)
        coef, _ = nnls(np.vstack(rows), np.asarray(target))
        return dataclasses.replace(self, coef=tuple(float(c) for c in coef), n_observations=len(obs))

    def ladder_costs(self, configs: Sequence[TrainConfig]) -> list[float]:
        """Predicted seconds of each rung (one config per rung)."""
        return [self.predict(c) for c in configs]


@dataclasses.dataclass(frozen=True)
class Plan:
    """The rungs a trial will climb and what each is predicted to cost."""

    budgets: tuple[int, ...]
    """Budgets [iterations] of rungs 0 … top."""
    costs: tuple[float, ...]
    """Predicted wall seconds of each of those rungs."""

    @property
    def total_s(self) -> float:
        """Predicted seconds if the trial climbs to its top."""
        return float(sum(self.costs))


def plan(configs: Sequence[TrainConfig], model: CostModel, cap_s: float, top: int | None = None) -> Plan | None:
    """Rungs 0 … the highest whose cumulative predicted cost fits ``cap_s`` (and ≤ ``top``); None: rung 0 does not.

    ``configs`` holds the configuration of every rung of the ladder (one element: a single training).
    """
    last = len(configs) - 1 if top is None else min(top, len(configs) - 1)
    costs: list[float] = []
    total = 0.0
    for config in configs[: last + 1]:
        c = model.predict(config)
        if total + c > cap_s:
            break
        costs.append(c)
        total += c
    if not costs:
        return None
    return Plan(tuple(int(c.train_iterations) for c in configs[: len(costs)]), tuple(costs))


def plan_one(configs: Sequence[TrainConfig], model: CostModel, cap_s: float, top: int | None = None) -> Plan | None:
    """The one rung a trial trains without its screens (a linear twin or neighbour): the highest rung ≤ ``top``
    whose own predicted cost fits ``cap_s`` (the driver passes ``[study] max_side_cost_s``); None: not even rung 0
    does. Priced alone, not as a ladder: such a trial never trains the rungs below (``plan`` would cap a crowd
    setting's twin on the whole road at 270k, where the view scored 69–74, for the rungs under its 810k training,
    which alone takes ~250 s)."""
    last = len(configs) - 1 if top is None else min(top, len(configs) - 1)
    for config in reversed(configs[: last + 1]):
        c = model.predict(config)
        if c <= cap_s:
            return Plan((int(config.train_iterations),), (c,))
    return None
