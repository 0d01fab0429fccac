"""The official score of a trained net: the ruleset's protocol, its net settings, the exact evaluation.

Library functions (the ``train`` command, the benches and the search objective call them): the
evaluation runs the net as the original harness would — float64 forward pass, the trained weights
after the JSON text round trip that turns NaN into 0, the original's ``Math.random`` seeding
(``autotune.learner.brain_policy``).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from autotune.convnet.netjson import NetSettings, dumps_net, loads_net
from autotune.learner.brain_policy import evaluate_net
from autotune.learner.config import TrainConfig
from sim.protocols import OFFICIAL, EvalResult

__all__ = ["OFFICIAL_PROTOCOL", "evaluate_official", "net_settings", "official_protocol"]

OFFICIAL_PROTOCOL = OFFICIAL  # ruleset -> its official evaluation protocol (``sim.protocols.OFFICIAL``)


def official_protocol(config: TrainConfig) -> str:
    """The ruleset's official evaluation: v2-official or v1-original."""
    return OFFICIAL_PROTOCOL[config.ruleset]


def net_settings(config: TrainConfig) -> NetSettings:
    """``netjson.NetSettings`` of a training config (what a net.js of this config would set)."""
    return NetSettings(
        lanes_side=config.lanes_side,
        patches_ahead=config.patches_ahead,
        patches_behind=config.patches_behind,
        temporal_window=config.temporal_window,
        other_agents=config.other_agents if config.ruleset == "v2" else None,
        epsilon_test_time=config.epsilon_test_time,
        train_iterations=config.train_iterations,
        experience_size=config.experience_size,
        start_learn_threshold=config.start_learn_threshold,
        gamma=config.gamma,
        learning_steps_total=config.learning_steps_total,
        learning_steps_burnin=config.learning_steps_burnin,
        epsilon_min=config.epsilon_min,
        learning_rate=config.learning_rate,
        momentum=config.momentum,
        batch_size=config.batch_size,
        l2_decay=config.l2_decay,
        l1_decay=config.l1_decay if config.l1_decay else None,
        trainer_method=config.method,
        engine_version=config.ruleset,
    )


def evaluate_official(
    convnet: Any,
    config: TrainConfig,
    seed: int | None = None,
    protocol: str | None = None,
    other_agents: int | None = None,
    engine_load: bool = True,
    gauss_cache: int = 0,
    progress: Callable[[int, int], None] | None = None,
) -> EvalResult:
    """Exact official-protocol evaluation of a trained net (after the JSON text round trip).

    ``progress(frames_done, total)`` is called between chunks of runs (wall-time limits: it may raise
    to abandon the evaluation; the scores do not depend on it).

    ``seed`` is the protocol's ``Math.random`` seed (default: the protocol's own, 1 for v2-official
    and 2000 for v1-original; learner_scores*.json use 100 + training seed, and in v1 no engine-load
    draws: ``engine_load=False``, see ``BrainPolicy.prepare``). ``gauss_cache``: convnetjs's Gaussian
    cache flag before the brain build (0 in a fresh process; the learner_scores.json harness
    evaluated in the training's process, so there it is the training's final flag).
    """
    net = loads_net(dumps_net(convnet))  # train.js saves with toJSON, evaluate.js loads with fromJSON
    return evaluate_net(
        net,
        net_settings(config),
        protocol or official_protocol(config),
        seed=seed,
        other_agents=other_agents,
        engine_load=engine_load,
        gauss_cache=gauss_cache,
        progress=progress,
    )
