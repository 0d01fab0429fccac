"""Memory layout of the batched world state (struct-of-arrays, leading worlds axis).

Compiled code receives a handful of dense arrays instead of per-car objects:

* ``cars``  float64 (W, 5, 20): per field, the 20 cars (index 0 = ego, 1…n agents in v2).
  Fields are in the golden traces' order ``x, y, lane_b, a, c`` (lane as a double, as in JS).
* ``grid``  float64 (W, 7, 70): the occupancy grid of the current frame.
* ``fs``    float64 (W, NF): per-world float scalars (camera term, accumulators).
* ``ints``  int64 (W, NI): per-world integer scalars (frame counter, generator states, …).
* ``mrand`` int64 (W,): the world's ``Math.random`` (mulberry32) state.
* ``cfg``   int64 (NC,): the engine configuration shared by all worlds.
"""

from __future__ import annotations

N_CARS = 20
N_LANES = 7
N_ROWS = 70

# car fields
CX, CY, CB, CA, CC = 0, 1, 2, 3, 4
N_CAR_FIELDS = 5

# float scalars
F_CAMERA = 0  # camera term t / E used by the next frame's moves
F_REWARD_ACC = 1  # reward accumulator I (v1) / N (v2)
F_SCORE_SUM = 2  # evaluation sum G (v1) / O (v2) over the current run
F_EGO_SUM = 3  # v2: Σ max(0, c0·a0) of the current run (ego-only statistics); v1: same as G
F_LAST_REWARD = 4  # (I − 60)/20 handed to the ego at its latest decision
N_FS = 5

# integer scalars
I_FRAME = 0  # frame counter of the current run (F / G in the specs)
I_ACTION = 1  # v1: the ego action m in force (persists between decisions)
I_DECIDER = 2  # car waiting for an action in the current frame, −1 if none
I_RUN_COUNTER = 3  # v2: the engine's run counter r (run seed = r after reset)
I_PM_U = 4  # v2: placement generator u
I_PM_V = 5  # v2: traffic generator v
I_RUNS_DONE = 6  # runs completed by this world
I_DONE = 7  # 1 once the world has completed all its runs
N_INTS = 8

# engine configuration
K_RULESET = 0  # 1 = v1, 2 = v2
K_LANES_SIDE = 1
K_AHEAD = 2
K_BEHIND = 3
K_AGENTS = 4
K_FRAMES = 5  # frames per run
K_RUNS = 6  # runs per world
N_CFG = 7

RULESET_CODES = {"v1": 1, "v2": 2}
