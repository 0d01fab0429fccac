"""Batched simulator: N independent worlds, stepped decision by decision for a Python policy.

``Simulator`` owns the struct-of-arrays state (``sim.layout``) and exposes the loop every RL
tool expects::

    sim = Simulator(EngineConfig(lanes_side=1, patches_ahead=10), n_worlds=4096, frames_per_run=2000)
    sim.seed_independent(seed=0)
    obs = sim.start()
    while obs is not None:
        obs = sim.step(policy(obs))
    sim.scores  # (n_worlds, runs_per_world)

Each observation batch holds one deciding car per world that is waiting (the ego at frames
0, 30, …; in v2 agent i at frames 3i, 3i + 30, …). Nothing here knows about training.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from sim import engine, seeding
from sim.config import EngineConfig
from sim.layout import (
    CB,
    I_DONE,
    I_FRAME,
    I_RUNS_DONE,
    K_AGENTS,
    K_AHEAD,
    K_BEHIND,
    K_FRAMES,
    K_LANES_SIDE,
    K_RULESET,
    K_RUNS,
    N_CARS,
    N_CFG,
    N_FS,
    N_INTS,
    N_LANES,
    N_ROWS,
    RULESET_CODES,
)
from sim.rng import mulberry32_next


class PolicyError(ValueError):
    """A policy returned something the engine cannot apply (wrong shape, actions outside 0–4)."""


@dataclasses.dataclass
class Observation:
    """The cars that must decide now, one row per waiting world.

    ``inputs`` (N, D) float64: the learner input vectors (spec order and normalisation);
    ``lane`` (N,) int: the deciding car's target lane, 0 = leftmost; ``car`` (N,): 0 = ego,
    i = agent i; ``world`` (N,): world index; ``reward`` (N,): the ego's ``(I − 60)/20``, NaN for
    agents; ``speed`` (N,): speed setting ``a``; ``mph`` (N,): current speed ``20·c·a``;
    ``mrand`` (n_worlds,) int64: every world's ``Math.random`` (mulberry32) state — the simulator's
    own array: a policy that draws as the original did (``uniform``, or compiled code given this
    array) advances the world's stream in place.
    """

    inputs: np.ndarray
    lane: np.ndarray
    car: np.ndarray
    world: np.ndarray
    reward: np.ndarray
    speed: np.ndarray
    mph: np.ndarray
    mrand: np.ndarray = dataclasses.field(repr=False)

    def __len__(self) -> int:
        return int(self.inputs.shape[0])

    def uniform(self) -> np.ndarray:
        """One ``Math.random()`` draw per row from that world's stream (as the original policies draw)."""
        out = np.empty(len(self))
        for k, w in enumerate(self.world):
            self.mrand[w], out[k] = mulberry32_next(int(self.mrand[w]))
        return out


class Simulator:
    """``n_worlds`` worlds, each doing ``runs_per_world`` runs of ``frames_per_run`` frames."""

    def __init__(self, config: EngineConfig, n_worlds: int, frames_per_run: int, runs_per_world: int = 1) -> None:
        if n_worlds < 1:
            raise ValueError(f"n_worlds: must be ≥ 1, got {n_worlds}")
        if frames_per_run < 1:
            raise ValueError(f"frames_per_run: must be ≥ 1, got {frames_per_run}")
        if runs_per_world < 1:
            raise ValueError(f"runs_per_world: must be ≥ 1, got {runs_per_world}")
        self.config = config
        self.n_worlds = n_worlds
        self.frames_per_run = frames_per_run
        self.runs_per_world = runs_per_world
        w = n_worlds
        self.cars = np.zeros((w, 5, N_CARS))
        self.grid = np.zeros((w, N_LANES, N_ROWS))
        self.fs = np.zeros((w, N_FS))
        self.ints = np.zeros((w, N_INTS), dtype=np.int64)
        self.mrand = np.zeros(w, dtype=np.int64)
        self.cfg = np.zeros(N_CFG, dtype=np.int64)
        self.cfg[K_RULESET] = RULESET_CODES[config.ruleset]
        self.cfg[K_LANES_SIDE] = config.lanes_side
        self.cfg[K_AHEAD] = config.patches_ahead
        self.cfg[K_BEHIND] = config.patches_behind
        self.cfg[K_AGENTS] = config.other_agents
        self.cfg[K_FRAMES] = frames_per_run
        self.cfg[K_RUNS] = runs_per_world
        self.scores = np.full((w, runs_per_world), np.nan)
        self.ego_scores = np.full((w, runs_per_world), np.nan)
        self._obs = np.zeros((w, config.num_inputs))
        self._obs_car = np.full(w, -1, dtype=np.int64)
        self._obs_reward = np.zeros(w)
        self._actions = np.zeros(w, dtype=np.int64)
        self.run_seeds = np.full((w, runs_per_world), -1, dtype=np.int64)
        # the drivers' arguments, in order (the arrays are updated in place, never replaced)
        self._advance_args = (
            self.cars,
            self.grid,
            self.fs,
            self.ints,
            self.mrand,
            self.cfg,
            self._actions,
            self._obs,
            self._obs_car,
            self._obs_reward,
            self.scores,
            self.ego_scores,
            self.run_seeds,
        )
        self._seeded = False
        self._parallel = w >= 16  # below that, waking the thread pool costs more than it saves

    @property
    def seeded(self) -> bool:
        return self._seeded

    @property
    def state_arrays(self) -> tuple[np.ndarray, ...]:
        """``(cars, grid, fs, ints, mrand, cfg)``: the arguments every compiled driver starts with."""
        return self._advance_args[:6]

    # -- seeding -------------------------------------------------------------------------
    def _arrays(self) -> tuple[np.ndarray, ...]:
        return self.cars, self.fs, self.ints, self.mrand, self.cfg

    def seed_independent(self, seed: int) -> None:
        """World i gets seed ``seed + i`` (the ``custom`` protocol; v1-distribution uses seed 1000)."""
        fn = seeding.seed_v1 if self.config.ruleset == "v1" else seeding.seed_v2_independent
        for i in range(self.n_worlds):
            fn(*self._arrays(), i, seed + i)
        self._seeded = True

    def seed_stream(self, mrand_state: int, run_counter: int = 0) -> None:
        """One world continuing a ``Math.random`` stream, as the official protocols do.

        v1: the state is the stream's (e.g. ``mulberry32(2000)`` for evaluate.js); v2: the stream
        installed before a fresh engine load, evaluation mode (run k uses Park–Miller seed k + 1, or
        ``run_counter + k + 1``: the same harness on other runs).
        """
        if self.n_worlds != 1:
            raise ValueError("seed_stream: the sequential protocols use exactly one world")
        if self.config.ruleset == "v1":
            if run_counter:
                raise ValueError("seed_stream: run_counter is a v2 evaluation's; v1 draws its runs from the stream")
            seeding.seed_v1(*self._arrays(), 0, mrand_state)
        else:
            seeding.seed_v2_evaluation(*self._arrays(), 0, mrand_state, int(run_counter))
        self._seeded = True

    def seed_per_run(self, seeds: list[int] | np.ndarray) -> None:
        """v1, one world: ``Math.random := mulberry32(seeds[k])`` right before run k's reset.

        The v1-distribution protocol for a policy with memory (a network's temporal window
        persists across runs): one world, re-seeded per run, instead of independent worlds.
        """
        if self.config.ruleset != "v1" or self.n_worlds != 1:
            raise ValueError("seed_per_run: per-run re-seeding is a v1 protocol on one world")
        seeds = np.asarray(seeds, dtype=np.int64)
        if seeds.shape != (self.runs_per_world,):
            raise ValueError(f"seed_per_run: need {self.runs_per_world} seeds, got {seeds.shape}")
        self.run_seeds[0] = seeds & 0xFFFFFFFF
        seeding.seed_v1(*self._arrays(), 0, int(seeds[0]))
        self._seeded = True

    def seed_training(self, mrand_state: int, brain_draws: int = 1) -> None:
        """v2 training-mode seeding (one world): seeds drawn from ``Math.random`` after the load."""
        if self.config.ruleset == "v1":
            self.seed_stream(mrand_state)
            return
        if self.n_worlds != 1:
            raise ValueError("seed_training: training uses exactly one world per trial")
        seeding.seed_v2_training(*self._arrays(), 0, mrand_state, brain_draws)
        self._seeded = True

    # -- stepping ------------------------------------------------------------------------
    def _advance(self) -> Observation | None:
        fn = engine.advance_batch if self._parallel else engine.advance_one
        fn(*self._advance_args)
        pending = self._obs_car >= 0
        n_pending = int(np.count_nonzero(pending))
        if n_pending == 0:
            return None
        if n_pending == self.n_worlds:
            worlds = np.arange(self.n_worlds)
            inputs = self._obs
        else:
            worlds = np.flatnonzero(pending)
            inputs = self._obs[worlds]
        cars = self._obs_car[worlds]
        speeds = np.empty((len(worlds), 2))
        engine.car_speeds(self.cars, worlds, cars, speeds)
        self._pending = worlds
        return Observation(
            inputs=inputs,
            lane=self.cars[worlds, CB, cars].astype(np.int64),
            car=cars,
            world=worlds,
            reward=self._obs_reward[worlds],
            speed=speeds[:, 0],
            mph=speeds[:, 1],
            mrand=self.mrand,
        )

    def start(self) -> Observation | None:
        """Run every world to its first decision."""
        if not self._seeded:
            raise RuntimeError("seed the simulator (seed_independent / seed_stream) before start()")
        self._pending = np.zeros(0, dtype=np.int64)
        return self._advance()

    def step(self, actions: np.ndarray) -> Observation | None:
        """Answer the pending decisions (one action per observation row) and run to the next ones."""
        actions = check_actions(actions, len(self._pending))
        self._actions[self._pending] = actions
        return self._advance()

    # -- lean single-world loop (training) ----------------------------------------------
    def start_single(self) -> int:
        """Single-world fast path: run to the first decision; returns the deciding car (−1: done).

        The observation is left in ``obs_inputs[0]`` and ``obs_reward[0]``; no objects are built.
        """
        if not self._seeded:
            raise RuntimeError("seed the simulator before start_single()")
        engine.advance_one(*self._advance_args)
        return int(self._obs_car[0])

    def step_single(self, action: int) -> int:
        """Answer world 0's pending decision (trusted action 0–4) and run to the next one.

        The training loop's hot path: one compiled call, no checks, no objects.
        """
        self._actions[0] = action
        engine.advance_one(*self._advance_args)
        return int(self._obs_car[0])

    def step_single_agents(self, action: int, agent_actions: np.ndarray, pos: int) -> tuple[int, int]:
        """``step_single``, with the other cars' decisions answered inline from ``agent_actions[pos:]``
        (int64, trusted 0–4) until the ego must decide again, the world ends, or they are used up.

        Returns (the deciding car or −1, the new ``pos``); a car other than the ego comes back only when
        the actions ran out, observed like ``step_single``'s.
        """
        self._actions[0] = action
        pos = engine.advance_one_agents(*self._advance_args, agent_actions, pos)
        return int(self._obs_car[0]), pos

    @property
    def obs_inputs(self) -> np.ndarray:
        """(n_worlds, D) buffer holding each waiting world's latest observation."""
        return self._obs

    @property
    def obs_reward(self) -> np.ndarray:
        """(n_worlds,) the ego's reward at its latest decision (NaN for agents)."""
        return self._obs_reward

    @property
    def obs_car(self) -> np.ndarray:
        """(n_worlds,) the car waiting in each world (−1 when none)."""
        return self._obs_car

    @property
    def done(self) -> bool:
        return bool(np.all(self.ints[:, I_DONE] != 0))

    @property
    def frames_simulated(self) -> int:
        """Frames simulated so far over all worlds."""
        done_runs = self.ints[:, I_RUNS_DONE]
        current = np.where(self.ints[:, I_DONE] != 0, 0, self.ints[:, I_FRAME])
        return int(done_runs.sum() * self.frames_per_run + current.sum())

    def run_compiled(self, policy, pstate, max_runs: int | None = None) -> int:  # noqa: ANN001
        """Drive world 0 through (at most ``max_runs`` of) its remaining runs, policy compiled inline.

        Returns the number of runs completed so far.
        """
        if self.n_worlds != 1:
            raise ValueError("run_compiled: compiled policies drive exactly one world")
        if not self._seeded:
            raise RuntimeError("seed the simulator before run_compiled()")
        obs = np.zeros(self.config.num_inputs)
        engine.run_compiled(
            *self.state_arrays,
            0,
            policy,
            pstate,
            obs,
            self.scores,
            self.ego_scores,
            self.run_seeds,
            self.runs_per_world if max_runs is None else max_runs,
        )
        return int(self.ints[0, I_RUNS_DONE])


def check_actions(actions: object, n: int) -> np.ndarray:
    """Validate a policy's answer: n integer actions in 0–4, else a ``PolicyError`` naming the problem."""
    arr = np.asarray(actions)
    if arr.shape != (n,):
        raise PolicyError(f"policy returned shape {arr.shape}; expected ({n},): one action per observation row")
    if arr.dtype.kind == "f":
        if not np.all(np.isfinite(arr)) or not np.all(arr == np.floor(arr)):
            raise PolicyError("policy returned non-integer actions; expected integers 0–4")
    elif arr.dtype.kind not in "iub":
        raise PolicyError(f"policy returned dtype {arr.dtype}; expected integer actions 0–4")
    out = arr.astype(np.int64)
    if n and (out.min() < 0 or out.max() > 4):
        bad = out[(out < 0) | (out > 4)][0]
        raise PolicyError(
            f"policy returned action {bad}; allowed actions are 0–4 (noop, accelerate, decelerate, left, right)"
        )
    return out
