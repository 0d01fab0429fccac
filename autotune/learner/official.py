"""The official score of a trained net: the ruleset's protocol in the config's own engine, the exact evaluation.

Library functions (the ``train`` command, the benches and the search objective call them): the
evaluation runs the net as the original harness would — float64 forward pass, the trained weights
after the JSON text round trip that turns NaN into 0, the original's ``Math.random`` seeding
(``autotune.learner.brain_policy``) — in ``TrainConfig.engine_config`` with the config's temporal
window and ε_test.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from autotune.convnet.netjson import dumps_net, loads_net
from autotune.learner.brain_policy import brain_evaluation, evaluate_brain
from autotune.learner.config import TrainConfig
from sim.config import ConfigError, EngineConfig
from sim.policies import NUM_ACTIONS
from sim.protocols import OFFICIAL, PROTOCOLS, EvalResult, SequentialEvaluation

__all__ = [
    "OFFICIAL_PROTOCOL",
    "EpsilonScreens",
    "evaluate_official",
    "official_protocol",
    "screen_epsilons",
    "screen_order",
    "screen_survivors",
]

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


def screen_order(epsilon: float, median: float, mean: float) -> tuple[float, float, float]:
    """The sort key of an ε_test screen (larger is better): the site's statistic, then the mean, then the smaller
    ε_test."""
    return (median, mean, -epsilon)


def screen_survivors(values: int, stages: int) -> tuple[int, ...]:
    """How many ε_test values each stage of ``screen_epsilons`` screens: every value on the first, then the better
    half (rounded down, at least one) of the stage before."""
    out = [values]
    for _ in range(stages - 1):
        out.append(max(1, out[-1] // 2))
    return tuple(out)


@dataclasses.dataclass
class EpsilonScreens:
    """One trained net's official evaluation begun at several ε_test values (``screen_epsilons``).

    ``screens[i]`` scores ``grid[i]`` on the protocol's first ``screens[i].runs`` runs — exactly the whole
    protocol's first runs at that ε_test: ``runs`` (the last stage) for the values that reached it, a shorter
    stage for those dropped earlier — and ``finish(i)`` carries that evaluation on to the whole protocol, so the
    runs it screened on are not run again. ``net_json`` is the net's JSON text (the one round trip every
    evaluation shares)."""

    grid: tuple[float, ...]
    runs: int
    """The runs of the last stage (the screens of ``finalists``)."""
    net_json: str
    screens: list[EvalResult]
    frames: int
    """Frames simulated so far: the screens', then those of ``finish``'s remaining runs."""
    _config: TrainConfig
    _protocol: str
    _net: Any
    _paused: list[SequentialEvaluation | None]
    stages: tuple[int, ...] = ()
    """The runs of each stage (``screen_epsilons``); ``(runs,)`` for one."""
    greedy: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, NUM_ACTIONS), dtype=np.int64))
    """How often each action (columns) was the net's greedy choice in each value's screen (rows, as ``grid``), over
    the runs it reached (``BrainPolicy.greedy_actions``): the best finalist's are those of the official
    evaluation's first ``runs`` runs, which ``finish`` completes, so a static policy is known before it (the
    search's ``prune_static``)."""

    @property
    def finalists(self) -> list[int]:
        """Indices of the values screened on the last stage's ``runs`` (every value with one stage)."""
        return [i for i, ev in enumerate(self.screens) if ev.runs == self.runs]

    @property
    def best(self) -> int:
        """The best finalist by ``screen_order``."""
        return max(self.finalists, key=lambda i: screen_order(self.grid[i], self.screens[i].median_site,
                                                              self.screens[i].mean))  # fmt: skip

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
    runs: int | Sequence[int],
    *,
    protocol: str | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> EpsilonScreens:
    """Score a trained net at each ε_test of ``grid`` on the official protocol's first ``runs`` runs.

    ``runs``: one count (every value screened on that many runs) or increasing counts, a successive halving:
    every value on the first, the better half (``screen_survivors``, ranked by ``screen_order``) carried on to
    the next, and so on; ``EpsilonScreens.best`` is the best on the last. Each screen is what
    ``evaluate_official(convnet, config at that ε_test, runs=n)`` gives for the runs n it reached, to the digit;
    the net's JSON round trip is done once for all of them, and on the sequential protocols (v2-official,
    v1-original) a screen carried on is continued, not restarted, and the finalists stay paused so that
    ``finish`` completes the chosen one instead of starting over.
    """
    protocol = protocol or official_protocol(config)
    proto = PROTOCOLS.get(protocol)
    stages = (int(runs),) if isinstance(runs, (int, np.integer)) else tuple(int(r) for r in runs)
    total = proto.runs if proto is not None else stages[-1] if stages else 0
    increasing = all(b > a for a, b in zip(stages, stages[1:], strict=False))
    if not stages or not increasing or any(not 1 <= r <= total for r in stages):
        raise ConfigError(f"runs: a screen runs 1 to {total} of {protocol}'s runs, in increasing stages; got "
                          f"{list(stages) if len(stages) != 1 else stages[0]}")  # fmt: skip
    net_json = dumps_net(convnet)
    net = loads_net(net_json)  # train.js saves with toJSON, evaluate.js loads with fromJSON
    engine = config.engine_config
    sequential = proto is not None and proto.sequential
    values = tuple(float(e) for e in grid)
    screens: list[EvalResult | None] = [None] * len(values)
    paused: list[SequentialEvaluation | None] = [None] * len(values)
    frames = 0
    alive = list(range(len(values)))

    greedy = np.zeros((len(values), NUM_ACTIONS), dtype=np.int64)

    def order(i: int) -> tuple[float, float, float]:
        ev = screens[i]
        assert ev is not None
        return screen_order(values[i], ev.median_site, ev.mean)

    for stage, keep in zip(stages, screen_survivors(len(values), len(stages)), strict=True):
        if len(alive) > keep:  # the better half of the last stage goes on; the others' worlds are freed
            alive = sorted(sorted(alive, key=order, reverse=True)[:keep])
            paused = [p if i in alive else None for i, p in enumerate(paused)]
        for i in alive:
            if sequential:
                ev = paused[i]
                if ev is None:
                    ev = paused[i] = brain_evaluation(net, engine, config.temporal_window, values[i], protocol)
                done = ev.runs_done
                ev.advance(stage - done, progress=progress)
                frames += (stage - done) * ev.frames
                screens[i] = ev.result()
                greedy[i] = ev.policy.greedy_actions
            else:
                result = evaluate_brain(net, engine, config.temporal_window, values[i], protocol, runs=stage,
                                        progress=progress, greedy_actions=greedy[i])  # fmt: skip
                frames += result.runs * result.frames
                screens[i] = result
    done_screens = [ev for ev in screens if ev is not None]
    assert len(done_screens) == len(values)
    return EpsilonScreens(values, stages[-1], net_json, done_screens, frames, config, protocol, net, paused,
                          stages, greedy)  # fmt: skip
