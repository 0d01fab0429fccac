"""The official score of a trained net: the ruleset's protocol in the config's own engine, the exact evaluation.

Library functions (the ``train`` command, the benches and the search objective call them): the
evaluation runs the net as the original harness would — float64 forward pass, the trained weights
after the JSON text round trip that turns NaN into 0, the original's ``Math.random`` seeding
(``autotune.learner.brain_policy``) — in ``TrainConfig.engine_config`` with the config's temporal
window and ε_test.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any

import numpy as np

from autotune.convnet.netjson import dumps_net, loads_net
from autotune.learner.brain_policy import evaluate_brain
from autotune.learner.config import TrainConfig
from sim.config import EngineConfig
from sim.protocols import OFFICIAL, EvalResult

__all__ = ["OFFICIAL_PROTOCOL", "evaluate_official", "official_protocol"]

OFFICIAL_PROTOCOL = OFFICIAL  # ruleset -> its official evaluation protocol (``sim.protocols.OFFICIAL``)


def official_protocol(config: TrainConfig) -> str:
    """The ruleset's official evaluation: v2-official or v1-original."""
    return OFFICIAL_PROTOCOL[config.ruleset]


def evaluate_official(
    convnet: Any,
    config: TrainConfig,
    seed: int | None = None,
    protocol: str | None = None,
    other_agents: int | None = None,
    engine_load: bool = True,
    gauss_cache: int = 0,
    progress: Callable[[int, int], None] | None = None,
    greedy_actions: np.ndarray | None = None,
    runs: int | None = None,
) -> EvalResult:
    """Exact official-protocol evaluation of a trained net (after the JSON text round trip).

    ``progress(frames_done, total)`` is called between chunks of runs (wall-time limits: it may raise
    to abandon the evaluation; the scores do not depend on it).

    ``seed`` is the protocol's ``Math.random`` seed (default: the protocol's own, 1 for v2-official
    and 2000 for v1-original; learner_scores*.json use 100 + training seed, and in v1 no engine-load
    draws: ``engine_load=False``, see ``BrainPolicy.prepare``). ``other_agents`` replaces the
    config's (v2). ``gauss_cache``: convnetjs's Gaussian cache flag before the brain build (0 in a
    fresh process; the learner_scores.json harness evaluated in the training's process, so there it
    is the training's final flag). ``greedy_actions`` (5 int64s), when given, receives how often each action
    was the net's greedy choice (``BrainPolicy.greedy_actions``; the scores do not depend on it). ``runs`` stops
    the protocol after its first ``runs`` runs (the same runs as the whole protocol's first ones).
    """
    net = loads_net(dumps_net(convnet))  # train.js saves with toJSON, evaluate.js loads with fromJSON
    engine = config.engine_config
    if other_agents is not None:
        engine = EngineConfig(**{**dataclasses.asdict(engine), "other_agents": other_agents})
    return evaluate_brain(
        net,
        engine,
        config.temporal_window,
        config.epsilon_test_time,
        protocol or official_protocol(config),
        seed=seed,
        engine_load=engine_load,
        gauss_cache=gauss_cache,
        progress=progress,
        greedy_actions=greedy_actions,
        runs=runs,
    )
