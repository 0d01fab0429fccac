"""The other agents of a v2 world during training: frozen brain copies that never learn (spec v2 §8.3)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from autotune.convnet.deepqlearn import (
    BLOCK,
    GREEDY,
    BlockUniform,
    explore_action,
    js_argmax_rows,
    js_epsilon,
    shift_window,
    warmup_action,
)
from autotune.learner.brain import DeepQLearner
from autotune.learner.config import TrainConfig
from autotune.learner.js_learner import OriginalStream
from autotune.learner.kernel import numpy_forward_ops
from sim.simulator import Simulator

__all__ = ["TrainingAgents"]


class TrainingAgents:
    """The v2 agents during training: frozen brain copies that never learn (spec v2 §8.3).

    Before the ego has made more than tw decisions the load-time copies are in their warm-up
    (action 0, v2 §13). The copy taken then has ``age = tw + 1``, so its ε is
    ``min(1, max(ε_min, 1 − (tw + 1 − burnin)/(total − burnin)))`` — 1 for every burnin > tw + 1:
    uniformly random actions. With a smaller burnin the copies act greedily with probability 1 − ε,
    on the network frozen at that moment, each with its own temporal window.

    ``blind`` (ε = 1 on the agents' own generator, the usual case): each decision is the same two
    draws, ``rf`` and ``⌊5u⌋``, so the actions are drawn a block ahead (``random_actions``) and the
    training loop lets the simulator answer them inline (``Simulator.step_single_agents``), the
    same draws in the same order as deciding one by one.
    """

    def __init__(
        self,
        config: TrainConfig,
        brain: DeepQLearner,
        seed: np.random.SeedSequence,
        stream: OriginalStream | None = None,
    ) -> None:
        self.config = config
        self.brain = brain
        self.rng = np.random.default_rng(seed)
        self._stream = stream
        # the copies draw from the same Math.random as everything else when there is a stream
        self._uniform: Callable[[], float] = stream.uniform if stream is not None else BlockUniform(self.rng)
        self.tw = config.temporal_window
        self.epsilon = js_epsilon(
            self.tw + 1, config.learning_steps_burnin, config.learning_steps_total, config.epsilon_min
        )
        self.frozen: Any = None
        self._hist: np.ndarray | None = None
        self.blind = stream is None and self.epsilon >= 1.0  # never greedy: no input is looked at
        self._actions = np.zeros(0, dtype=np.int64)
        self.pos = 0  # the next of ``_actions``

    def random_actions(self) -> np.ndarray:
        """``blind`` agents' next actions, ``_actions[pos:]`` (never empty): each block of ``BLOCK``
        uniforms is ``BlockUniform``'s next one, read as ``(rf, u)`` pairs, action ``⌊5u⌋``."""
        if self.pos >= len(self._actions):
            self._actions = (5.0 * self.rng.random(BLOCK)[1::2]).astype(np.int64)
            self.pos = 0
        return self._actions

    def step_to_ego(self, sim: Simulator, action: int) -> tuple[int, int]:
        """Answer the ego's ``action`` and every ``blind`` agent decision after it inside ``sim`` (up to the ego's
        next decision, the end, or this block's last action); returns (the deciding car or −1, agent decisions)."""
        actions = self.random_actions()
        start = self.pos
        car, self.pos = sim.step_single_agents(action, actions, start)
        return car, self.pos - start

    def act(self, car: int, inputs: np.ndarray) -> int:
        if self.brain.forward_passes <= self.tw:
            return warmup_action(True, self._uniform)  # load-time copies, v2 warm-up: 0, no draw
        if self.blind:
            action = int(self.random_actions()[self.pos])
            self.pos += 1
            return action
        action = explore_action(self._uniform, self.epsilon)  # always random when ε = 1
        return self._greedy(car, inputs) if action == GREEDY else action

    def _greedy(self, car: int, inputs: np.ndarray) -> int:
        brain = self.brain
        if self.frozen is None:
            import copy

            dtype = brain._hist.dtype
            self.frozen = numpy_forward_ops(copy.deepcopy(brain.module), brain.layers, dtype)
            self._hist = np.tile(brain._hist, (self.config.other_agents + 1, 1))
        hist = self._hist[car]  # type: ignore[index]
        x = np.concatenate([np.asarray(inputs, dtype=hist.dtype), hist])
        if self._stream is not None:
            self._stream.vol(self.config.net_inputs)
        h = x
        for op in self.frozen:
            h = op(h)
        action = int(js_argmax_rows(h[None, :])[0])
        if self.tw:
            shift_window(hist, inputs, action, brain.num_states)
        return action
