"""Ruleset dispatch and the compiled drivers built on the split frame.

The drivers step the same ``frame_pre``/``frame_post`` pair (``engine_v1``, ``engine_v2``);
there is no second, slower copy of the rules:

* ``advance_batch`` — many worlds in parallel (``prange``): each world runs frames until one of
  its cars must decide, writes that car's observation and stops, so a Python policy can answer
  all pending decisions of all worlds in one call. Runs end and restart (``reset()``) inside.
* ``drive_world`` — one world through whole runs with a compiled policy called inside the loop
  (inlined into its caller, so a caller naming a global policy is cached): the official
  protocols are sequential by nature (v2 runs are coupled through ``reset()``, v1-original is one
  random stream), so they need one fast world rather than many; ``sim.policies.run_builtin``
  runs it over many worlds in parallel, and ``run_compiled`` takes any policy as an argument.
* ``advance_one`` — ``advance_batch`` for one world without the thread pool (training), and
  ``advance_one_agents``, which answers the other cars' decisions inline from a list of actions
  and stops only at the ego's (a training run's agents acting at random, spec v2 §8.3).

A run's score is ``⌊(sum/frames)·2000⌋/100`` (v1 §9, v2 §11): mean mph truncated to 2 decimals.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from sim.engine_v1 import frame_post_v1, frame_pre_v1, observe_v1, reset_v1
from sim.engine_v2 import frame_post_v2, frame_pre_v2, observe_v2, reset_v2
from sim.layout import (
    CA,
    CB,
    CC,
    F_EGO_SUM,
    F_LAST_REWARD,
    F_SCORE_SUM,
    I_DECIDER,
    I_DONE,
    I_FRAME,
    I_RUNS_DONE,
    K_FRAMES,
    K_RULESET,
    K_RUNS,
)

V1 = 1


@njit(cache=True, error_model="numpy", inline="always")
def run_score(total: float, frames: int) -> float:
    """Mean mph of a run truncated (not rounded) to 2 decimals, in the original's operation order."""
    return math.floor((total / frames) * 2000.0) / 100.0


@njit(cache=True, error_model="numpy")
def reset(cars: np.ndarray, fs: np.ndarray, ints: np.ndarray, mr: np.ndarray, cfg: np.ndarray, w: int) -> None:
    """The engine's ``reset()`` for world ``w`` (draws from the world's generators)."""
    if cfg[K_RULESET] == V1:
        reset_v1(cars, fs, ints, mr, w)
    else:
        reset_v2(cars, fs, ints, mr, cfg, w)


@njit(cache=True, error_model="numpy", inline="always")
def frame_pre(
    cars: np.ndarray, grid: np.ndarray, fs: np.ndarray, ints: np.ndarray, mr: np.ndarray, cfg: np.ndarray, w: int
) -> int:
    """First half of a frame; returns the car that must decide now, or −1."""
    if cfg[K_RULESET] == V1:
        return frame_pre_v1(cars, grid, fs, ints, mr, w)
    return frame_pre_v2(cars, grid, fs, ints, cfg, w)


@njit(cache=True, error_model="numpy", inline="always")
def frame_post(
    cars: np.ndarray, grid: np.ndarray, fs: np.ndarray, ints: np.ndarray, cfg: np.ndarray, w: int, action: int
) -> None:
    """Second half of a frame, with the pending car's action (ignored when nobody decided)."""
    if cfg[K_RULESET] == V1:
        frame_post_v1(cars, grid, fs, ints, w, action)
    else:
        frame_post_v2(cars, grid, fs, ints, cfg, w, action)


@njit(cache=True, error_model="numpy", inline="always")
def observe(cars: np.ndarray, grid: np.ndarray, cfg: np.ndarray, w: int, car: int, out: np.ndarray) -> None:
    """Input vector of ``car`` in world ``w`` from the grid as it is now."""
    if cfg[K_RULESET] == V1:
        observe_v1(cars, grid, cfg, w, out)
    else:
        observe_v2(cars, grid, cfg, w, car, out)


@njit(cache=True, error_model="numpy", inline="always")
def _finish_run(fs: np.ndarray, ints: np.ndarray, cfg: np.ndarray, w: int, scores: np.ndarray, ego: np.ndarray) -> bool:
    """Record the score of the run that just ended; True when the world has done all its runs."""
    frames = cfg[K_FRAMES]
    k = ints[w, I_RUNS_DONE]
    scores[w, k] = run_score(fs[w, F_SCORE_SUM], frames)
    ego[w, k] = run_score(fs[w, F_EGO_SUM], frames)
    ints[w, I_RUNS_DONE] = k + 1
    if k + 1 >= cfg[K_RUNS]:
        ints[w, I_DONE] = 1
        return True
    return False


@njit(cache=True, error_model="numpy", inline="always")
def _next_run(
    cars: np.ndarray, fs: np.ndarray, ints: np.ndarray, mr: np.ndarray, cfg: np.ndarray, w: int, run_seeds: np.ndarray
) -> None:
    """Reset for the next run; protocols that re-seed ``Math.random`` per run do it right before."""
    seed = run_seeds[w, ints[w, I_RUNS_DONE]]
    if seed >= 0:
        mr[w] = seed
    reset(cars, fs, ints, mr, cfg, w)


@njit(cache=True, error_model="numpy", inline="always")
def end_run(
    cars: np.ndarray,
    fs: np.ndarray,
    ints: np.ndarray,
    mr: np.ndarray,
    cfg: np.ndarray,
    w: int,
    scores: np.ndarray,
    ego: np.ndarray,
    run_seeds: np.ndarray,
) -> bool:
    """A run of world ``w`` has played its frames: record its score, then reset for the next run.

    True when the world has done all its runs (nothing is reset). The seam for a driver of its own
    (``drive_world``'s loop with something else inline, e.g. the learner's exact training run).
    """
    if _finish_run(fs, ints, cfg, w, scores, ego):
        return True
    _next_run(cars, fs, ints, mr, cfg, w, run_seeds)
    return False


_NO_ACTIONS = np.zeros(0, dtype=np.int64)
"""No inline answers: every decision goes back to the caller (``advance_batch``, ``advance_one``)."""


@njit(cache=True, error_model="numpy", inline="always")
def _advance_world(
    cars: np.ndarray,
    grid: np.ndarray,
    fs: np.ndarray,
    ints: np.ndarray,
    mr: np.ndarray,
    cfg: np.ndarray,
    w: int,
    actions: np.ndarray,
    obs: np.ndarray,
    obs_car: np.ndarray,
    obs_reward: np.ndarray,
    scores: np.ndarray,
    ego: np.ndarray,
    run_seeds: np.ndarray,
    agent_actions: np.ndarray,
    pos: int,
) -> int:
    """Apply world ``w``'s pending action, then run it to the next decision that ``agent_actions[pos:]`` does not
    answer (the other cars', in order) and observe it, or to its end. Returns the new ``pos``."""
    obs_car[w] = -1
    if ints[w, I_DONE] != 0:
        return pos
    if ints[w, I_DECIDER] >= 0:
        frame_post(cars, grid, fs, ints, cfg, w, actions[w])
    frames = cfg[K_FRAMES]
    n = agent_actions.shape[0]
    while True:
        if ints[w, I_FRAME] >= frames:
            if _finish_run(fs, ints, cfg, w, scores, ego):
                return pos
            _next_run(cars, fs, ints, mr, cfg, w, run_seeds)
        car = frame_pre(cars, grid, fs, ints, mr, cfg, w)
        if car > 0 and pos < n:
            frame_post(cars, grid, fs, ints, cfg, w, agent_actions[pos])
            pos += 1
        elif car >= 0:
            observe(cars, grid, cfg, w, car, obs[w])
            obs_car[w] = car
            obs_reward[w] = fs[w, F_LAST_REWARD] if car == 0 else math.nan
            return pos
        else:
            frame_post(cars, grid, fs, ints, cfg, w, -1)


@njit(cache=True, error_model="numpy", parallel=True)
def advance_batch(
    cars: np.ndarray,
    grid: np.ndarray,
    fs: np.ndarray,
    ints: np.ndarray,
    mr: np.ndarray,
    cfg: np.ndarray,
    actions: np.ndarray,
    obs: np.ndarray,
    obs_car: np.ndarray,
    obs_reward: np.ndarray,
    scores: np.ndarray,
    ego: np.ndarray,
    run_seeds: np.ndarray,
) -> None:
    """Apply each pending world's action, then run every world to its next decision (or its end)."""
    for w in prange(cars.shape[0]):
        _advance_world(
            cars, grid, fs, ints, mr, cfg, w, actions, obs, obs_car, obs_reward, scores, ego, run_seeds, _NO_ACTIONS, 0
        )


@njit(cache=True, error_model="numpy")
def advance_one(
    cars: np.ndarray,
    grid: np.ndarray,
    fs: np.ndarray,
    ints: np.ndarray,
    mr: np.ndarray,
    cfg: np.ndarray,
    actions: np.ndarray,
    obs: np.ndarray,
    obs_car: np.ndarray,
    obs_reward: np.ndarray,
    scores: np.ndarray,
    ego: np.ndarray,
    run_seeds: np.ndarray,
) -> None:
    """``advance_batch`` without the thread pool: the cheapest call for one world (training)."""
    for w in range(cars.shape[0]):
        _advance_world(
            cars, grid, fs, ints, mr, cfg, w, actions, obs, obs_car, obs_reward, scores, ego, run_seeds, _NO_ACTIONS, 0
        )


@njit(cache=True, error_model="numpy")
def advance_one_agents(
    cars: np.ndarray,
    grid: np.ndarray,
    fs: np.ndarray,
    ints: np.ndarray,
    mr: np.ndarray,
    cfg: np.ndarray,
    actions: np.ndarray,
    obs: np.ndarray,
    obs_car: np.ndarray,
    obs_reward: np.ndarray,
    scores: np.ndarray,
    ego: np.ndarray,
    run_seeds: np.ndarray,
    agent_actions: np.ndarray,
    pos: int,
) -> int:
    """``advance_one`` for world 0 that answers the other cars' decisions inline, in order, from
    ``agent_actions[pos:]`` (no observation is built for them): it stops at the ego's decision, at the
    world's end, or at a car's decision once those actions are used up (observed as ``advance_one``
    would). Returns the new ``pos``. The frames are ``advance_one``'s, one decision per call
    apart: a training run whose other agents act without looking (spec v2 §8.3, ε = 1) needs no
    trip to Python per agent decision."""
    return _advance_world(
        cars, grid, fs, ints, mr, cfg, 0, actions, obs, obs_car, obs_reward, scores, ego, run_seeds, agent_actions, pos
    )


@njit(error_model="numpy", inline="always")
def drive_world(
    cars: np.ndarray,
    grid: np.ndarray,
    fs: np.ndarray,
    ints: np.ndarray,
    mr: np.ndarray,
    cfg: np.ndarray,
    w: int,
    policy,  # noqa: ANN001 - a numba-compiled policy function (see sim.policies)
    pstate,  # noqa: ANN001 - that policy's own state (any numba-typed value)
    obs: np.ndarray,
    scores: np.ndarray,
    ego: np.ndarray,
    run_seeds: np.ndarray,
    max_runs: int,
) -> None:
    """Run world ``w`` (already reset) through at most ``max_runs`` more runs, ``policy`` inline.

    ``policy(inputs, lane, car, reward, mr, w, pstate) -> action`` (``sim.policies``). Inlined
    into its caller, so a caller naming a global policy compiles (and caches) a static call.
    """
    frames = cfg[K_FRAMES]
    done = 0
    while ints[w, I_DONE] == 0 and done < max_runs:
        done += 1
        for _ in range(frames - ints[w, I_FRAME]):
            car = frame_pre(cars, grid, fs, ints, mr, cfg, w)
            action = -1
            if car >= 0:
                observe(cars, grid, cfg, w, car, obs)
                reward = fs[w, F_LAST_REWARD] if car == 0 else math.nan
                action = policy(obs, int(cars[w, CB, car]), car, reward, mr, w, pstate)
            frame_post(cars, grid, fs, ints, cfg, w, action)
        if not _finish_run(fs, ints, cfg, w, scores, ego):
            _next_run(cars, fs, ints, mr, cfg, w, run_seeds)


# ``drive_world`` as a function of its own, for any compiled policy passed as an argument: a
# function-typed argument makes it uncacheable, so it compiles once per process and policy.
run_compiled = njit(error_model="numpy")(drive_world.py_func)


@njit(cache=True, error_model="numpy")
def car_speeds(cars: np.ndarray, w: np.ndarray, car: np.ndarray, out: np.ndarray) -> None:
    """Speed setting ``a`` and current mph ``20·c·a`` of the given cars (for observations)."""
    for k in range(w.shape[0]):
        out[k, 0] = cars[w[k], CA, car[k]]
        out[k, 1] = 20.0 * cars[w[k], CC, car[k]] * cars[w[k], CA, car[k]]
