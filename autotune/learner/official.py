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
from autotune.learner.brain_policy import brain_evaluation, evaluate_brain
from autotune.learner.config import TrainConfig
from sim.config import ConfigError, EngineConfig
from sim.protocols import OFFICIAL, PROTOCOLS, EvalResult, SequentialEvaluation

__all__ = ["OFFICIAL_PROTOCOL", "EpsilonScreens", "evaluate_official", "official_protocol", "screen_epsilons"]

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


@dataclasses.dataclass
class EpsilonScreens:
    """One trained net's official evaluation begun at several ε_test values (``screen_epsilons``).

    ``screens[i]`` scores ``grid[i]`` on the protocol's first ``runs`` runs — exactly the whole protocol's first
    runs at that ε_test — and ``finish(i)`` carries that evaluation on to the whole protocol, so the runs it
    screened on are not run again. ``net_json`` is the net's JSON text (the one round trip every evaluation
    shares)."""

    grid: tuple[float, ...]
    runs: int
    net_json: str
    screens: list[EvalResult]
    frames: int
    """Frames simulated so far: the screens', then those of ``finish``'s remaining runs."""
    _config: TrainConfig
    _protocol: str
    _net: Any
    _paused: list[SequentialEvaluation | None]

    def finish(
        self,
        index: int,
        progress: Callable[[int, int], None] | None = None,
        greedy_actions: np.ndarray | None = None,
    ) -> EvalResult:
        """The whole official evaluation at ``grid[index]`` (``evaluate_official``'s result, exactly), continued
        from its screen; ``greedy_actions`` as ``evaluate_official``'s (over every run)."""
        paused = self._paused[index]
        if paused is None:  # not paused (independent worlds, or another screen finished): evaluate from the start
            config = self._config
            ev = evaluate_brain(self._net, config.engine_config, config.temporal_window, self.grid[index],
                                self._protocol, progress=progress, greedy_actions=greedy_actions)  # fmt: skip
            self.frames += ev.runs * ev.frames
            return ev
        before = paused.runs_done
        paused.advance(progress=progress)
        self.frames += (paused.runs_done - before) * paused.frames
        self._paused = [p if i == index else None for i, p in enumerate(self._paused)]  # free the others' worlds
        if greedy_actions is not None:
            greedy_actions[:] = paused.policy.greedy_actions
        return paused.result()


def screen_epsilons(
    convnet: Any,
    config: TrainConfig,
    grid: tuple[float, ...] | list[float],
    runs: int,
    *,
    protocol: str | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> EpsilonScreens:
    """Score a trained net at each ε_test of ``grid`` on the official protocol's first ``runs`` runs.

    Each screen is what ``evaluate_official(convnet, config at that ε_test, runs=runs)`` gives, to the digit;
    the net's JSON round trip is done once for all of them, and on the sequential protocols (v2-official,
    v1-original) each screen stays paused so that ``finish`` completes the chosen one instead of starting over.
    """
    protocol = protocol or official_protocol(config)
    proto = PROTOCOLS.get(protocol)
    total = proto.runs if proto is not None else runs
    if not 1 <= runs <= total:
        raise ConfigError(f"runs: a screen runs 1 to {total} of {protocol}'s runs, got {runs}")
    net_json = dumps_net(convnet)
    net = loads_net(net_json)  # train.js saves with toJSON, evaluate.js loads with fromJSON
    engine = config.engine_config
    screens: list[EvalResult] = []
    paused: list[SequentialEvaluation | None] = []
    for epsilon in grid:
        if proto is not None and proto.sequential:
            ev = brain_evaluation(net, engine, config.temporal_window, float(epsilon), protocol)
            ev.advance(runs, progress=progress)
            screens.append(ev.result())
            paused.append(ev)
        else:
            screens.append(evaluate_brain(net, engine, config.temporal_window, float(epsilon), protocol, runs=runs,
                                          progress=progress))  # fmt: skip
            paused.append(None)
    frames = sum(ev.runs * ev.frames for ev in screens)
    return EpsilonScreens(tuple(float(e) for e in grid), runs, net_json, screens, frames, config, protocol, net,
                          paused)  # fmt: skip
