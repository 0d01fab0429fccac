"""Golden traces: the batched engine reproduces every frame of the original, in every world.

All worlds of one batch are stepped together; each world carries a different trace, and every
car state, camera term, accumulator, decision input, reward, action and generator position is
compared bit for bit after every frame.
"""

from __future__ import annotations

import numpy as np
import pytest

from sim import engine, seeding
from sim.config import EngineConfig
from sim.layout import (
    F_CAMERA,
    F_LAST_REWARD,
    F_REWARD_ACC,
    F_SCORE_SUM,
    I_ACTION,
    I_PM_U,
    I_PM_V,
    I_RUN_COUNTER,
)
from sim.policies import BUILTINS
from sim.rng import mulberry32_advance
from sim.simulator import Simulator
from tests.conftest import load_json

CONFIG_KW = dict(lanes_side=1, patches_ahead=10, patches_behind=0)


def _first_mismatch(got: list, expected: list, what: str) -> None:
    """Compare per-frame records in bulk; on failure name the first frame that differs."""
    a = np.array(got, dtype=float)
    b = np.array(expected, dtype=float)
    if a.shape == b.shape and np.array_equal(a, b):
        return
    bad = np.flatnonzero(np.any((a != b).reshape(len(a), -1), axis=1)) if a.shape == b.shape else [0]
    k = int(bad[0])
    where = np.argwhere(a[k] != b[k])[0] if a.shape == b.shape else ()
    raise AssertionError(
        f"{what}: first mismatch at frame {k}, index {tuple(int(i) for i in where)}: "
        f"got {a[k][tuple(where)]!r} expected {b[k][tuple(where)]!r}"
    )


def _step_frame(sim: Simulator, w: int, policy, trace_decisions: list, cursor: list[int]) -> None:
    obs = np.zeros(sim.config.num_inputs)
    car = engine.frame_pre(sim.cars, sim.grid, sim.fs, sim.ints, sim.mrand, sim.cfg, w)
    action = -1
    if car >= 0:
        engine.observe(sim.cars, sim.grid, sim.cfg, w, car, obs)
        dec = trace_decisions[cursor[w]]
        cursor[w] += 1
        frame = int(sim.ints[w, 0])
        assert (dec["frame"], dec.get("car", 0)) == (frame, car), f"world {w}: decision at frame {frame} car {car}"
        np.testing.assert_array_equal(
            obs, np.array(dec["state"], dtype=float), err_msg=f"world {w} frame {frame} input"
        )
        if car == 0:
            assert sim.fs[w, F_LAST_REWARD] == dec["reward"], f"world {w} frame {frame} reward"
        action = int(policy.compiled(obs, int(sim.cars[w, 2, car]), car, 0.0, sim.mrand, w, policy.pstate))
        assert action == dec["action"]
    engine.frame_post(sim.cars, sim.grid, sim.fs, sim.ints, sim.cfg, w, action)


def test_v1_golden_traces_batched(reference):
    traces = [load_json(reference / f"golden_traces/heuristic_a_seed{s}.json.gz") for s in (1, 2, 3)]
    config = EngineConfig(ruleset="v1", **CONFIG_KW)
    sim = Simulator(config, n_worlds=3, frames_per_run=3000)
    sim.seed_independent(1)  # world i ↦ mulberry32(1 + i) = the traces' seeds
    policy = BUILTINS["heuristic_a"].bind(config)
    cursor = [0, 0, 0]
    for w, tr in enumerate(traces):
        np.testing.assert_array_equal(sim.cars[w].T, np.array(tr["initial"]["cars"]))
    cars: list[list] = [[], [], []]
    scalars: list[list] = [[], [], []]
    for _ in range(3000):
        for w in range(3):
            _step_frame(sim, w, policy, traces[w]["decisions"], cursor)
            cars[w].append(sim.cars[w].T.copy())
            scalars[w].append([sim.fs[w, F_CAMERA], sim.fs[w, F_REWARD_ACC], sim.ints[w, I_ACTION], sim.mrand[w]])
    for w, tr in enumerate(traces):
        _first_mismatch(cars[w], [fr["cars"] for fr in tr["frames"]], f"world {w} cars")
        draws = 60 + np.cumsum([len(fr["randoms"]) for fr in tr["frames"]])
        expected = [
            [fr["t"], fr["I"], fr["m"], st]
            for fr, st in zip(tr["frames"], _stream_positions(tr["seed"], draws), strict=True)
        ]
        _first_mismatch(scalars[w], expected, f"world {w} camera/I/m/stream")
    for w, tr in enumerate(traces):
        assert sim.fs[w, F_SCORE_SUM] == tr["G"]
        assert engine.run_score(sim.fs[w, F_SCORE_SUM], 3000) == tr["score"]
        assert cursor[w] == len(tr["decisions"])


def _stream_positions(seed: int, cumulative_draws) -> list[int]:
    """mulberry32 state after each frame's cumulative draw count (checks every frame's draws)."""
    out, state, done = [], seed, 0
    for n in cumulative_draws:
        state = mulberry32_advance(state, int(n) - done)
        done = int(n)
        out.append(state)
    return out


@pytest.mark.parametrize("agents", [0, 10])
def test_v2_golden_traces_batched(reference, agents):
    traces = [load_json(reference / f"golden_traces_v2/heuristic_a_agents{agents}_seed{s}.json.gz") for s in (1, 2)]
    config = EngineConfig(ruleset="v2", other_agents=agents, **CONFIG_KW)
    sim = Simulator(config, n_worlds=2, frames_per_run=2000)
    args = (sim.cars, sim.fs, sim.ints, sim.mrand, sim.cfg)
    # world 0: the official protocol's run 0 from a fresh engine load
    seeding.seed_v2_official(*args, 0, 1)
    # world 1: run 1, from the state the trace records just before its reset()
    tr1 = traces[1]
    sim.ints[1, I_PM_V] = tr1["v_state_before_reset"]
    sim.ints[1, I_RUN_COUNTER] = tr1["pm_seed"] - 1
    sim.mrand[1] = mulberry32_advance(1, 40)  # 20 draws at engine load + 20 in run 0's reset
    engine.reset(*args, 1)
    for w, tr in enumerate(traces):
        init = tr["initial"]
        np.testing.assert_array_equal(sim.cars[w].T, np.array(init["cars"]))
        assert (sim.ints[w, I_PM_U], sim.ints[w, I_PM_V]) == (init["u_state"], init["v_state"])
        assert sim.ints[w, I_RUN_COUNTER] == init["seeds"]["r"]
    policy = BUILTINS["heuristic_a"].bind(config)
    cursor = [0, 0]
    cars: list[list] = [[], []]
    scalars: list[list] = [[], []]
    for _ in range(2000):
        for w in range(2):
            _step_frame(sim, w, policy, traces[w]["decisions"], cursor)
            cars[w].append(sim.cars[w].T.copy())
            scalars[w].append(
                [sim.fs[w, F_CAMERA], sim.fs[w, F_REWARD_ACC], sim.fs[w, F_SCORE_SUM], sim.ints[w, I_PM_V]]
            )
    for w, tr in enumerate(traces):
        _first_mismatch(cars[w], [fr["cars"] for fr in tr["frames"]], f"world {w} cars")
        v_state = tr["initial"]["v_state"]
        expected = []
        for fr in tr["frames"]:  # the traffic generator's position after each frame
            v_draws = [value for gen, value in fr["draws"] if gen == "v"]
            v_state = v_draws[-1] if v_draws else v_state
            expected.append([fr["t"], fr["N"], fr["O"], v_state])
        _first_mismatch(scalars[w], expected, f"world {w} camera/N/O/traffic")
    for w, tr in enumerate(traces):
        assert engine.run_score(sim.fs[w, F_SCORE_SUM], 2000) == tr["score"]
        assert cursor[w] == len(tr["decisions"])


def test_step_api_matches_trace_decisions(reference):
    """The production loop (advance_batch + Python policy) sees the same inputs as the trace."""
    traces = [load_json(reference / f"golden_traces/heuristic_a_seed{s}.json.gz") for s in (1, 2, 3)]
    config = EngineConfig(ruleset="v1", **CONFIG_KW)
    sim = Simulator(config, n_worlds=3, frames_per_run=3000)
    sim.seed_independent(1)
    policy = BUILTINS["heuristic_a"].bind(config)
    obs = sim.start()
    j = 0
    while obs is not None:
        for w in range(3):
            dec = traces[w]["decisions"][j]
            np.testing.assert_array_equal(obs.inputs[w], np.array(dec["state"], dtype=float))
            assert obs.reward[w] == dec["reward"] and obs.lane[w] == dec["ego_lane"] and obs.speed[w] == dec["ego_a"]
        obs = sim.step(policy(obs))
        j += 1
    assert sim.scores[:, 0].tolist() == [tr["score"] for tr in traces]
