"""Run replays, data first: one evaluation run of a trained net recorded frame by frame (issue 9 §4).

The paper draws a run from four views — the road with the cars, the occupancy grid, the safety
system's view and the learner's input slice. ``record_run`` steps one world of the exact engine
frame by frame (``Simulator.state_arrays`` with ``sim.engine``'s public ``frame_pre`` /
``observe`` / ``frame_post``, the same split frame every compiled driver uses) with the net's
exact evaluation-time brain (``BrainPolicy``: temporal window, ε draws, v2 agents sharing the net)
as the policy, and keeps every view as arrays. ``dashboards.replay_render`` draws them; tests
check the arrays (the run's score equals ``evaluate_net``'s for the same seed, the grid holds the
cars, the input slice is what the policy received).

The run is the ``custom`` protocol's world for ``seed`` (``evaluate_net(…, "custom", seed=seed,
runs=1, frames=run_frames)`` scores the same run). ``frames``/``every`` choose what is kept; the
run always goes to its end so that the score is the run's.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from autotune.convnet.settings import Settings
from autotune.convnet.spec import ConvNet
from autotune.learner.brain_policy import BrainPolicy, engine_config
from sim import engine, rules
from sim.config import ConfigError, EngineConfig
from sim.layout import CA, CB, CC, CX, CY, F_EGO_SUM, F_LAST_REWARD, F_SCORE_SUM, N_CARS, N_LANES, N_ROWS
from sim.protocols import CUSTOM, PROTOCOLS
from sim.simulator import Simulator

LANE_PX = 20  # a lane is 20 px wide (spec §1)
ROW_PX = 10  # a grid row is 10 px tall
CAR_W, CAR_H = 12, 34  # drawn car size [px]; the grid footprint is ox ∈ {0, 10}, oy ∈ {0 … 30}
FREE = {"v1": 7.0, "v2": 100.0}  # the value of an empty cell (v1 §1, v2 §1)
ACTIONS = ("noop", "accelerate", "decelerate", "left", "right")
KIND_EGO, KIND_AGENT, KIND_TRAFFIC = 0, 1, 2

# safety view cell codes (0: not examined)
SAFE_SPEED_FREE = 1  # one of the 4 rows ahead the speed rule reads: free
SAFE_SPEED_BLOCK = 2  # …occupied: caps the ego's safety factor c
SAFE_LANE_FREE = 3  # a cell the lane-change rule reads for a move left/right: free
SAFE_LANE_BLOCK = 4  # …occupied: that move is refused
SAFETY_LABELS = ("not read", "speed: free", "speed: car ahead", "lane change: free", "lane change: blocked")


@dataclasses.dataclass(frozen=True)
class Recording:
    """One run's recorded frames (T of them, leading axis) and decisions (K), plus its score."""

    name: str
    """The net's name (file stem or study/trial)."""
    config: EngineConfig
    """Engine configuration of the run (ruleset, input slice size, other agents)."""
    seed: int
    """``custom``-protocol seed of the run (Park–Miller/mulberry32 seeding of world 0)."""
    run_frames: int
    """Frames in the whole run (the score is over these)."""
    every: int
    """Every ``every``-th frame was kept."""
    score: float
    """The run's score as the engine reports it (mph; v2: mean over ego and agents)."""
    ego_score: float
    """The ego's own score over the run (mph)."""
    kind: np.ndarray
    """(20,) int: 0 ego, 1 agent (v2, same net), 2 traffic."""
    frame: np.ndarray
    """(T,) frame index G of each kept frame."""
    x: np.ndarray
    """(T, 20) car x, left edge [px] (lane ℓ settled: 20ℓ + 4)."""
    y: np.ndarray
    """(T, 20) car y, top edge [px], 0 = top of the 700 px road; the ego stays near 525."""
    lane: np.ndarray
    """(T, 20) target lane b (0 = leftmost)."""
    speed: np.ndarray
    """(T, 20) speed setting a (the decision frame's action not yet applied)."""
    safety: np.ndarray
    """(T, 20) safety factor c ∈ [0, 2] from this frame's grid (c·a moves the car)."""
    mph: np.ndarray
    """(T, 20) 20·c·a after the frame's action: the speed the score counts [mph]."""
    running_score: np.ndarray
    """(T,) the run's score so far: mean of the score term over frames 0…G [mph]."""
    grid: np.ndarray
    """(T, 7, 70) occupancy grid [lane, row]: ``free`` where empty, else the occupant's c·a (v1 ego: 10·c·a ≥ free)."""
    free: float
    """Grid value of an empty cell (v1 7, v2 100)."""
    safety_cells: np.ndarray
    """(T, 7, 70) int8 safety view of the ego: the cells the speed and lane-change rules read (SAFE_* codes)."""
    can_left: np.ndarray
    """(T,) bool: a move left would succeed now (the engine's own rule, on a copy)."""
    can_right: np.ndarray
    """(T,) bool: a move right would succeed now."""
    inputs: np.ndarray
    """(T, rows, width) the ego's input slice now (grid ÷ free; rows ahead first, width = 2·lanes_side + 1)."""
    slice_lane0: np.ndarray
    """(T,) grid lane of the slice's first column (may be off the road: read as 0)."""
    slice_row0: np.ndarray
    """(T,) grid row of the slice's first (farthest ahead) row."""
    decider: np.ndarray
    """(T,) car deciding on the frame (−1: none)."""
    action: np.ndarray
    """(T,) its action 0–4 (−1: none)."""
    decision_frame: np.ndarray
    """(K,) frame of every decision in the kept span (all of them, not only every ``every``-th)."""
    decision_car: np.ndarray
    """(K,) the deciding car."""
    decision_action: np.ndarray
    """(K,) the action the net chose."""
    decision_inputs: np.ndarray
    """(K, D) the input vector the policy received (the latest state; the window is the brain's)."""

    def __len__(self) -> int:
        return int(self.frame.shape[0])

    @property
    def lanes_side(self) -> int:
        return self.config.lanes_side

    @property
    def ruleset(self) -> str:
        return self.config.ruleset


def safety_view(
    grid: np.ndarray, x: float, y: float, lane: float, a: float, free: float
) -> tuple[np.ndarray, tuple[int, int]]:
    """The ego's safety view: the cells the speed rule (4 rows ahead) and lane-change rule read, coded.

    Same cells as ``sim.rules.safety_factor`` / ``try_lane_change`` (v1 §4–§5, v2 §5–§6): column
    ``⌊(x + 7.5)/20⌋`` (the lane when settled), rows ``⌊y/10⌋ − k``, k = 1…4; for a move by ±1 the
    column beside it, rows ``⌊y/10 + h⌋`` for h = −3a, −3a + 1, … < 4. Returns the codes and the
    number of lane-change cells read (left, right) — cells off the grid count as blocked.
    """
    codes = np.zeros((N_LANES, N_ROWS), dtype=np.int8)
    col = int(lane) if x == 20.0 * lane + 4.0 else math.floor((x + 7.5) / 20.0)
    base = math.floor(y / 10.0)
    if 0 <= col < N_LANES:
        for k in range(1, 5):
            row = base - k
            if 0 <= row < N_ROWS:
                codes[col, row] = SAFE_SPEED_BLOCK if grid[col, row] < free else SAFE_SPEED_FREE
    counts = []
    for direction in (-1.0, 1.0):
        target = math.floor((x + 7.5) / 20.0 + direction)
        h = 3.0 * (-a)
        n = 0
        while h < 4.0:
            row = math.floor(y / 10.0 + h)
            if 0 <= target < N_LANES and 0 <= row < N_ROWS:
                codes[target, row] = SAFE_LANE_FREE if grid[target, row] >= free else SAFE_LANE_BLOCK
            n += 1
            h = h + 1.0
        counts.append(n)
    return codes, (counts[0], counts[1])


def record_run(
    net: ConvNet,
    settings: Settings,
    *,
    name: str = "net",
    ruleset: str | None = None,
    seed: int = 0,
    frames: int = 600,
    every: int = 1,
    run_frames: int | None = None,
    other_agents: int | None = None,
    epsilon: float | None = None,
) -> Recording:
    """Drive one ``custom``-protocol run (world ``seed``) with the net's exact brain; keep frames 0, every, … < frames.

    ``ruleset`` defaults to the net's engine; ``run_frames`` to the protocol's 2,000 (at least
    ``frames``); ``other_agents`` (v2) to the net's; ``epsilon`` to its ``epsilon_test_time``.
    """
    if frames < 1:
        raise ConfigError(f"frames: must be ≥ 1, got {frames}")
    if every < 1:
        raise ConfigError(f"every: must be ≥ 1, got {every}")
    ruleset = ruleset or settings.engine
    config = engine_config(settings, ruleset, other_agents)
    run_frames = max(frames, PROTOCOLS[CUSTOM].frames) if run_frames is None else run_frames
    if run_frames < frames:
        raise ConfigError(f"run_frames: must be ≥ frames ({frames}), got {run_frames}")
    free = FREE[config.ruleset]

    sim = Simulator(config, n_worlds=1, frames_per_run=run_frames, runs_per_world=1)
    sim.seed_independent(seed)
    brain = settings.filled()
    eps = brain.epsilon_test_time if epsilon is None else epsilon
    policy = BrainPolicy(net, config, brain.temporal_window, eps, name=name)
    policy.prepare(CUSTOM, seed, runs=1)
    pstate = policy.pstate
    decide = policy.compiled
    cars, grid, fs, ints, mr, cfg = sim.state_arrays

    n_keep = len(range(0, frames, every))
    width = 2 * config.lanes_side + 1
    rows = config.patches_ahead + config.patches_behind
    rec: dict[str, np.ndarray] = {
        "frame": np.zeros(n_keep, dtype=np.int64),
        **{k: np.zeros((n_keep, N_CARS)) for k in ("x", "y", "lane", "speed", "safety", "mph")},
        "running_score": np.zeros(n_keep),
        "grid": np.zeros((n_keep, N_LANES, N_ROWS)),
        "safety_cells": np.zeros((n_keep, N_LANES, N_ROWS), dtype=np.int8),
        "can_left": np.zeros(n_keep, dtype=bool),
        "can_right": np.zeros(n_keep, dtype=bool),
        "inputs": np.zeros((n_keep, rows, width)),
        "slice_lane0": np.zeros(n_keep, dtype=np.int64),
        "slice_row0": np.zeros(n_keep, dtype=np.int64),
        "decider": np.full(n_keep, -1, dtype=np.int64),
        "action": np.full(n_keep, -1, dtype=np.int64),
    }
    decisions: list[tuple[int, int, int, np.ndarray]] = []
    obs = np.zeros(config.num_inputs)
    ego_obs = np.zeros(config.num_inputs)
    probe = np.empty_like(cars)
    j = 0
    for t in range(run_frames):
        car = int(engine.frame_pre(cars, grid, fs, ints, mr, cfg, 0))
        action = -1
        if car >= 0:
            engine.observe(cars, grid, cfg, 0, car, obs)
            reward = fs[0, F_LAST_REWARD] if car == 0 else math.nan
            action = int(decide(obs, int(cars[0, CB, car]), car, reward, mr, 0, pstate))
            if t < frames:
                decisions.append((t, car, action, obs.copy()))
        keep = t < frames and t % every == 0
        if keep:
            rec["frame"][j] = t
            for key, field in (("x", CX), ("y", CY), ("lane", CB), ("speed", CA), ("safety", CC)):
                rec[key][j] = cars[0, field]
            rec["grid"][j] = grid[0]
            ex, ey, eb, ea = (float(cars[0, f, 0]) for f in (CX, CY, CB, CA))
            rec["safety_cells"][j] = safety_view(grid[0], ex, ey, eb, ea, free)[0]
            for key, direction in (("can_left", -1.0), ("can_right", 1.0)):
                probe[:] = cars  # the engine's own lane-change rule, on a copy of the cars
                rec[key][j] = bool(rules.try_lane_change(grid[0], probe, 0, 0, direction, free))
            engine.observe(cars, grid, cfg, 0, 0, ego_obs)
            rec["inputs"][j] = ego_obs.reshape(rows, width)
            rec["slice_lane0"][j] = int(eb) - config.lanes_side
            top = 52 if config.ruleset == "v1" else math.floor(math.floor(ey) / 10.0)  # v1 §7: fixed rows
            rec["slice_row0"][j] = top - config.patches_ahead
            rec["decider"][j] = car
            rec["action"][j] = action
        engine.frame_post(cars, grid, fs, ints, cfg, 0, action)
        if keep:
            rec["mph"][j] = 20.0 * cars[0, CC] * cars[0, CA]
            rec["running_score"][j] = 20.0 * fs[0, F_SCORE_SUM] / (t + 1)
            j += 1
    other_agents = config.other_agents  # 0 in v1 (EngineConfig: v1 has no other agents)
    kind = np.full(N_CARS, KIND_TRAFFIC, dtype=np.int64)
    kind[0] = KIND_EGO
    kind[1 : other_agents + 1] = KIND_AGENT
    k = len(decisions)
    return Recording(
        name=name,
        config=config,
        seed=seed,
        run_frames=run_frames,
        every=every,
        score=float(engine.run_score(fs[0, F_SCORE_SUM], run_frames)),
        ego_score=float(engine.run_score(fs[0, F_EGO_SUM], run_frames)),
        kind=kind,
        free=free,
        decision_frame=np.array([d[0] for d in decisions], dtype=np.int64),
        decision_car=np.array([d[1] for d in decisions], dtype=np.int64),
        decision_action=np.array([d[2] for d in decisions], dtype=np.int64),
        decision_inputs=np.array([d[3] for d in decisions]).reshape(k, config.num_inputs),
        **rec,
    )


__all__ = [
    "ACTIONS",
    "FREE",
    "KIND_AGENT",
    "KIND_EGO",
    "KIND_TRAFFIC",
    "Recording",
    "SAFETY_LABELS",
    "record_run",
    "safety_view",
]
