"""Built-in fixed policies (engine_spec.md §13, v2 §15) and how user policies plug in.

A policy is any callable ``policy(obs) -> actions`` taking an ``Observation`` batch (``inputs``
(N, D), ``lane`` (N,), …) and returning N actions 0–4 — NumPy code, a torch network or a rule.
A policy may also carry a numba-compiled twin in its ``compiled`` attribute,
``compiled(inputs, lane, car, reward, mrand, w, pstate) -> int``, with its state in ``pstate``:
the sequential official protocols call that twin inside the compiled simulation loop.

``heuristic_a`` reads the state as the spec defines it for L = 1, P = 10, B = 0 and generalises
to any lanes_side ≥ 1 and patches_ahead ≥ 1 (behind rows are ignored): a cell is free iff its
value ≥ 1; ``gap(o)`` counts free cells from the row just ahead outwards.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np
from numba import njit, prange

from sim import engine
from sim.config import EngineConfig
from sim.rng import mrand
from sim.simulator import Observation, Simulator

NUM_ACTIONS = 5
ACTION_NAMES = ("noop", "accelerate", "decelerate", "left", "right")


@njit(cache=True, error_model="numpy")
def _noop(inputs, lane, car, reward, mr, w, pstate):  # noqa: ANN001, ANN202
    return 0


@njit(cache=True, error_model="numpy")
def _accelerate(inputs, lane, car, reward, mr, w, pstate):  # noqa: ANN001, ANN202
    return 1


@njit(cache=True, error_model="numpy")
def _decelerate(inputs, lane, car, reward, mr, w, pstate):  # noqa: ANN001, ANN202
    return 2


@njit(cache=True, error_model="numpy")
def _random(inputs, lane, car, reward, mr, w, pstate):  # noqa: ANN001, ANN202
    return int(math.floor(5.0 * mrand(mr, w)))


@njit(cache=True, error_model="numpy", inline="always")
def _gap(inputs: np.ndarray, width: int, ahead: int, column: int) -> int:
    n = 0
    for col in range(ahead - 1, -1, -1):
        if inputs[width * col + column] >= 1.0:
            n += 1
        else:
            break
    return n


@njit(cache=True, error_model="numpy")
def _heuristic_a(inputs, lane, car, reward, mr, w, pstate):  # noqa: ANN001, ANN202
    lanes_side = pstate[0]
    ahead = pstate[1]
    width = 2 * lanes_side + 1
    own = _gap(inputs, width, ahead, lanes_side)
    if own == ahead:
        return 1
    gl = _gap(inputs, width, ahead, lanes_side - 1)
    gr = _gap(inputs, width, ahead, lanes_side + 1)
    if gl >= gr and gl > own:
        return 3
    if gr > gl and gr > own:
        return 4
    return 1


@njit(cache=True, error_model="numpy", inline="always")
def _builtin(inputs, lane, car, reward, mr, w, pstate):  # noqa: ANN001, ANN202
    """Every built-in behind one static call: ``pstate = [lanes_side, patches_ahead, code]``."""
    code = pstate[2]
    if code == 4:
        return _heuristic_a(inputs, lane, car, reward, mr, w, pstate)
    if code == 3:
        return _random(inputs, lane, car, reward, mr, w, pstate)
    return code


@njit(cache=True, error_model="numpy", parallel=True)
def run_builtin(cars, grid, fs, ints, mr, cfg, pstate, scores, ego, run_seeds, first, last, n_inputs, max_runs):  # noqa: ANN001, ANN201
    """Worlds ``first … last − 1`` through at most ``max_runs`` more runs each, in parallel, policy inline.

    Each world runs to its end without returning to Python, so its state stays in cache and the
    threads never wait for each other between decisions.
    """
    for w in prange(first, last):
        obs = np.empty(n_inputs)
        engine.drive_world(cars, grid, fs, ints, mr, cfg, w, _builtin, pstate, obs, scores, ego, run_seeds, max_runs)


def _gap_batch(inputs: np.ndarray, width: int, ahead: int, column: int) -> np.ndarray:
    free = inputs[:, column : width * ahead : width][:, ::-1] >= 1.0  # rows just-ahead first
    blocked = ~free
    first_blocked = np.where(blocked.any(axis=1), blocked.argmax(axis=1), ahead)
    return first_blocked


@dataclasses.dataclass(frozen=True)
class BuiltinPolicy:
    """A fixed policy with a batched NumPy form and a compiled twin."""

    name: str
    batch: Callable[[Observation, EngineConfig], np.ndarray]
    compiled: Callable[..., int]
    code: int  # selects it inside ``_builtin``: 0–2 the constant action, 3 random, 4 heuristic_a

    def bind(self, config: EngineConfig) -> BoundPolicy:
        """The policy for one engine configuration (checks the input window it needs)."""
        if self.name == "heuristic_a" and (config.lanes_side < 1 or config.patches_ahead < 1):
            raise ValueError(
                "policy heuristic_a: needs lanes_side ≥ 1 and patches_ahead ≥ 1 "
                f"(got lanes_side={config.lanes_side}, patches_ahead={config.patches_ahead}); "
                "its reference setting is --lanes-side 1 --patches-ahead 10 --patches-behind 0"
            )
        return BoundPolicy(self, config)


@dataclasses.dataclass(frozen=True)
class BoundPolicy:
    """A built-in policy bound to an engine configuration: callable on observation batches."""

    spec: BuiltinPolicy
    config: EngineConfig

    @property
    def compiled(self) -> Callable[..., int]:
        return self.spec.compiled

    @property
    def pstate(self) -> np.ndarray:
        return np.array([self.config.lanes_side, self.config.patches_ahead, self.spec.code], dtype=np.int64)

    def __call__(self, obs: Observation) -> np.ndarray:
        return self.spec.batch(obs, self.config)

    def run(self, sim: Simulator, first: int = 0, last: int | None = None, max_runs: int | None = None) -> None:
        """Drive worlds ``first … last − 1`` of a seeded ``sim`` (at most ``max_runs`` more runs each).

        The compiled, parallel path: same decisions and draws as calling the policy on batches.
        """
        if sim.config != self.config:
            raise ValueError("run: the simulator's engine configuration differs from the policy's")
        if not sim.seeded:
            raise RuntimeError("seed the simulator before run()")
        last = sim.n_worlds if last is None else last
        if not 0 <= first <= last <= sim.n_worlds:  # the compiled loop does not bounds-check
            raise ValueError(f"run: need 0 ≤ first ≤ last ≤ n_worlds = {sim.n_worlds}, got first={first}, last={last}")
        if max_runs is not None and max_runs < 1:
            raise ValueError(f"run: max_runs must be ≥ 1, got {max_runs}")
        run_builtin(
            *sim.state_arrays,
            self.pstate,
            sim.scores,
            sim.ego_scores,
            sim.run_seeds,
            first,
            last,
            self.config.num_inputs,
            sim.runs_per_world if max_runs is None else max_runs,
        )


def _heuristic_batch(obs: Observation, config: EngineConfig) -> np.ndarray:
    width = 2 * config.lanes_side + 1
    ahead = config.patches_ahead
    own = _gap_batch(obs.inputs, width, ahead, config.lanes_side)
    gl = _gap_batch(obs.inputs, width, ahead, config.lanes_side - 1)
    gr = _gap_batch(obs.inputs, width, ahead, config.lanes_side + 1)
    out = np.ones(len(obs), dtype=np.int64)
    out[(gr > gl) & (gr > own)] = 4
    out[(gl >= gr) & (gl > own)] = 3
    out[own == ahead] = 1
    return out


def _constant(action: int) -> Callable[[Observation, EngineConfig], np.ndarray]:
    def batch(obs: Observation, config: EngineConfig) -> np.ndarray:
        return np.full(len(obs), action, dtype=np.int64)

    return batch


def _random_batch(obs: Observation, config: EngineConfig) -> np.ndarray:
    return np.floor(5.0 * obs.uniform()).astype(np.int64)


BUILTINS: dict[str, BuiltinPolicy] = {
    "noop": BuiltinPolicy("noop", _constant(0), _noop, 0),
    "accelerate": BuiltinPolicy("accelerate", _constant(1), _accelerate, 1),
    "decelerate": BuiltinPolicy("decelerate", _constant(2), _decelerate, 2),
    "random": BuiltinPolicy("random", _random_batch, _random, 3),
    "heuristic_a": BuiltinPolicy("heuristic_a", _heuristic_batch, _heuristic_a, 4),
}
