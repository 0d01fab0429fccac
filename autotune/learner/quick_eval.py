"""Quick evaluation of the current network: a batched greedy policy on the custom protocol (the learning curve)."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from autotune.convnet.deepqlearn import explore_rows, js_argmax_rows, shift_windows, warmup_rows
from autotune.learner.config import NUM_ACTIONS, TrainConfig
from sim.protocols import CUSTOM, EvalResult, evaluate

__all__ = ["QUICK_EVAL_SEED", "GreedyPolicy", "quick_evaluate"]


QUICK_EVAL_SEED = 1_000_000  # quick evaluations use custom-protocol seeds far from every official seed


# --------------------------------------------------------------------------------------------
# batched greedy policy (quick evaluation of the current network)
# --------------------------------------------------------------------------------------------


class GreedyPolicy:
    """A network as a batched simulator policy: per-(world, car) temporal windows, ε_test, warm-up.

    Each (world, car) behaves like a fresh evaluation-time brain (``learning = false``): its first
    ``tw`` decisions are warm-up actions (v1 random, v2 0), then ``rf < epsilon_test_time`` gives a
    random action, else greedy. Used for the quick scores during training; the exact, draw-for-draw
    evaluation of a trained net is ``autotune.learner.brain_policy``.
    """

    def __init__(self, module: Any, config: TrainConfig, rng: np.random.Generator | None = None) -> None:
        self.module = module
        self.config = config
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self.dtype = next(module.parameters()).dtype
        self.tw = config.temporal_window
        self.S = config.num_states
        self.stateful = self.tw > 0
        self.name = f"greedy[{config.hidden or 'linear'}]"
        self._slots = 1 + config.other_agents
        self._hist = np.zeros((0, self.tw * (self.S + NUM_ACTIONS)))
        self._fp = np.zeros(0, dtype=np.int64)

    def _grow(self, n: int) -> None:
        if n > self._fp.shape[0]:
            hist = np.zeros((n, self._hist.shape[1]))
            hist[: self._hist.shape[0]] = self._hist
            fp = np.zeros(n, dtype=np.int64)
            fp[: self._fp.shape[0]] = self._fp
            self._hist, self._fp = hist, fp

    def __call__(self, obs: Any) -> np.ndarray:
        n = len(obs)
        if n == 0:
            return np.zeros(0, dtype=np.int64)
        tw, S = self.tw, self.S
        slots = np.asarray(obs.world, dtype=np.int64) * self._slots + np.asarray(obs.car, dtype=np.int64)
        self._grow(int(slots.max()) + 1)
        self._fp[slots] += 1
        fp = self._fp[slots]
        x = obs.inputs if tw == 0 else np.concatenate([obs.inputs, self._hist[slots]], axis=1)
        with torch.inference_mode():
            q = self.module(torch.from_numpy(np.ascontiguousarray(x)).to(self.dtype)).double().numpy()
        actions = js_argmax_rows(q)
        explore_rows(actions, self.config.epsilon_test_time, self.rng)
        warmup_rows(actions, fp <= tw, self.config.ruleset == "v2", self.rng)
        if tw:
            h = self._hist[slots]
            shift_windows(h, obs.inputs, actions, S)
            self._hist[slots] = h
        return actions


def quick_evaluate(
    module: Any,
    config: TrainConfig,
    runs: int = 20,
    frames: int = 2000,
    seed: int = QUICK_EVAL_SEED,
    rng: np.random.Generator | None = None,
    threads: int | None = 1,
) -> EvalResult:
    """Short custom-protocol evaluation (``runs`` independent worlds × ``frames``) of the greedy net.

    ``threads``: numba threads for this evaluation only (None: the process's). One by default: a
    20-world batch is too small to amortise the parallel region's barriers, which become very slow
    when the other cores are busy (e.g. parallel trials). The process's own count is left as it is.
    """
    policy = GreedyPolicy(module, config, rng)
    return evaluate(config.engine_config, policy, CUSTOM, seed=seed, runs=runs, frames=frames, threads=threads)
