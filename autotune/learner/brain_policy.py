"""A trained convnetjs deepqlearn brain as a compiled simulator policy, exact to the original's draws.

Evaluation-time behaviour of ``deepqlearn.Brain.forward`` with ``learning = false``
(engine_spec.md §10.2–§10.6, engine_spec_v2.md §8.3, §13), per decision of a car:

* ``forward_passes += 1``. While ``forward_passes ≤ temporal_window`` (warm-up, the first tw
  decisions of a brain's life) no input is built and the action is random: v1 ``⌊5u⌋`` (one
  ``Math.random`` draw), v2 always 0 without a draw.
* Otherwise the input ``[x_t, x_{t−1}, e(a_{t−1}), …]`` is built (``e(a)`` = one-hot × num_states),
  ``rf`` is drawn (always), and if ``rf < ε_test`` the action is ``⌊5u⌋`` (one more draw); else the
  greedy action — ``policy()`` first allocates ``new Vol(1, 1, net_inputs)``, whose constructor draws
  ``net_inputs`` Gaussians from the Marsaglia-polar generator with its **global** one-value cache
  (2 ``Math.random`` draws per attempt, attempts with u² + v² = 0 or > 1 rejected), then runs the
  forward pass (no further draws) and scans the 5 Q-values with strict ``>``.
* The windows shift: the state, and the action, are appended (``window_size = max(tw, 2)``).

Building the brain (``new deepqlearn.Brain``) draws the initial fc weights: ``Σ in·out`` Gaussians
(one ``Vol(1, 1, in)`` per neuron; nothing else in the constructor, ``value_net.fromJSON`` or the
trainer draws). ``prepare()`` replays those draws from ``mulberry32(seed)`` so that the protocol
starts from the right ``Math.random`` state *and* Gaussian-cache state.

v2 agents (car i = 1…n) own brain copies. The copies taken at engine load make at most tw
decisions, all in the v2 warm-up (action 0, no draw), before the engine re-copies the main brain
once at the first frame where its ``forward_passes > temporal_window`` (spec v2 §8.3). Nothing
changes the main brain between that frame and the next agent decision, so the re-copy (windows,
counters) is done lazily at that decision. ``reset_seed(0)`` only feeds the v2 warm-up's
``⌊nextFloat()⌋·5`` = 0, so it needs no state.

All mutable state lives in numba arrays (``pstate``) with a leading world axis: the sequential
protocols use world 0; batched Python use (``__call__``) keeps one set of brains per world.

convnetjs's Gaussian cache is a module global, so a process that evaluates several nets in a row
carries the flag from one evaluation into the next brain build (``gauss_cache`` /
``final_gauss_cache``); evaluate.js and the site's web worker start fresh (flag 0, the default).

Usage::

    net, settings = autotune.convnet.netjson.load("nets/x.json")            # + x.config.json
    result = evaluate_net(net, settings, "v2-official")             # sim.protocols.EvalResult
    result = evaluate_net(net, settings, "v1-original", seed=2001)  # evaluate.js, one repetition

    policy = BrainPolicy.of_settings(net, settings, "v2")           # for sim.protocols.evaluate
    stream = policy.prepare("v2-official", seed=1)
    sim.protocols.evaluate(config, policy, "v2-official", stream_state=stream)
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit

from autotune.convnet.deepqlearn import (
    GREEDY,
    argmax_js,
    explore_action_mr,
    warmup_action_mr,
    window_input,
    window_push,
)
from autotune.convnet.forward import FlatNet, flatten, forward_flat
from autotune.convnet.netjson import check_sizes
from autotune.convnet.random import build_draws, gauss_skip
from autotune.convnet.settings import Settings
from autotune.convnet.spec import NUM_ACTIONS, ConvNet, net_input_size
from sim import engine
from sim.config import ConfigError, EngineConfig
from sim.protocols import (
    CUSTOM,
    PROTOCOLS,
    V1_DISTRIBUTION,
    V1_ORIGINAL,
    V2_HELDOUT,
    V2_OFFICIAL,
    V2_OFFICIAL_STREAM_SEED,
    EvalResult,
    ProgressFn,
    SequentialEvaluation,
    evaluate,
)
from sim.rng import mulberry32_advance
from sim.simulator import Simulator

MAX_BRAINS = 11  # the ego + up to 10 agents
SEQUENTIAL_PROTOCOLS = (V2_OFFICIAL, V2_HELDOUT, V1_ORIGINAL, V1_DISTRIBUTION)  # one world: the brain's own driver
V1_LOAD_DRAWS = 60  # loading the v1 engine constructs 20 cars, 3 draws each

# gcfg (int64) fields
G_RULESET, G_TW, G_NUM_STATES, G_NET_INPUTS, G_WINDOW, G_N_BRAINS = range(6)
N_GCFG = 6
# gflt (float64) fields
F_EPSILON = 0
N_GFLT = 1
# per-world state: the Gaussian cache flag, the agents' re-copy flag, then the greedy choices per action (all
# brains of the world; counted, never drawn from: the scores do not depend on them)
W_CACHE, W_COPIED, W_GREEDY = range(3)
N_WSTATE = W_GREEDY + NUM_ACTIONS
# per-brain state
B_FP, B_HEAD = range(2)
N_BSTATE = 2

RULESET_V1 = 1
RULESET_V2 = 2


@njit(cache=True, error_model="numpy", inline="always")
def _decide(inputs, mr, w, b, codes, params, gcfg, gflt, wstate, bstate, states, actions, netin, buf):  # noqa: ANN001, ANN202
    tw = gcfg[G_TW]
    ns = gcfg[G_NUM_STATES]
    fp = bstate[w, b, B_FP] + 1
    bstate[w, b, B_FP] = fp
    head = bstate[w, b, B_HEAD]
    if fp > tw:
        action = explore_action_mr(mr, w, gflt[F_EPSILON])
        if action == GREEDY:
            wstate[w, W_CACHE] = gauss_skip(mr, w, wstate[w, W_CACHE], gcfg[G_NET_INPUTS])
            window_input(netin, inputs, states[w, b], actions[w, b], head, tw, ns)
            out = forward_flat(codes, params, netin, buf)
            action = argmax_js(buf, out, NUM_ACTIONS)
            wstate[w, W_GREEDY + action] += 1
    else:
        action = warmup_action_mr(mr, w, gcfg[G_RULESET] == RULESET_V2)
    bstate[w, b, B_HEAD] = window_push(states[w, b], actions[w, b], head, inputs, action, ns)
    return action


@njit(cache=True, error_model="numpy")
def brain_policy(inputs, lane, car, reward, mr, w, pstate):  # noqa: ANN001, ANN201
    """Compiled policy ``(inputs, lane, car, reward, mr, w, pstate) -> action`` (sim.policies protocol)."""
    codes, params, gcfg, gflt, wstate, bstate, states, actions, netin, buf = pstate
    b = car
    if car > 0:
        n_brains = gcfg[G_N_BRAINS]
        if car >= n_brains:
            return 0
        if wstate[w, W_COPIED] == 0:
            if bstate[w, 0, B_FP] > gcfg[G_TW]:
                # the engine's one re-copy of the main brain into every agent (spec v2 §8.3)
                for j in range(1, n_brains):
                    for f in range(bstate.shape[2]):
                        bstate[w, j, f] = bstate[w, 0, f]
                    for k in range(states.shape[2]):
                        actions[w, j, k] = actions[w, 0, k]
                        for d in range(states.shape[3]):
                            states[w, j, k, d] = states[w, 0, k, d]
                wstate[w, W_COPIED] = 1
            else:
                return 0  # load-time copy, still in the v2 warm-up: action 0, no draw
    return _decide(inputs, mr, w, b, codes, params, gcfg, gflt, wstate, bstate, states, actions, netin, buf)


@njit(cache=True, error_model="numpy")
def _decide_rows(inputs, cars, worlds, mr, pstate, out):  # noqa: ANN001, ANN202
    for r in range(inputs.shape[0]):
        out[r] = brain_policy(inputs[r], 0, cars[r], math.nan, mr, worlds[r], pstate)


@njit(cache=True, error_model="numpy")
def run_brain(cars, grid, fs, ints, mr, cfg, w, pstate, obs, scores, ego, run_seeds, max_runs):  # noqa: ANN001, ANN201
    """``sim.engine.drive_world`` with ``brain_policy`` bound statically, so that numba can cache it.

    (A function passed as an argument cannot be cached; compiling the generic driver costs ~10 s
    per process.) World ``w`` (already reset), at most ``max_runs`` more runs.
    """
    engine.drive_world(cars, grid, fs, ints, mr, cfg, w, brain_policy, pstate, obs, scores, ego, run_seeds, max_runs)


class BrainPolicy:
    """An evaluation-time deepqlearn brain (``learning = false``) driving the ego and the v2 agents.

    ``compiled``/``pstate`` plug into ``sim.protocols.evaluate``; call ``prepare(protocol, seed)``
    first — it resets the brains and returns the ``stream_state`` to pass to ``evaluate``.
    ``__call__(obs)`` answers batched observations (one brain set per world).
    """

    stateful = True

    def __init__(
        self,
        net: ConvNet,
        engine: EngineConfig,
        temporal_window: int,
        epsilon: float,
        *,
        n_worlds: int = 1,
        name: str | None = None,
    ) -> None:
        check_sizes(net, engine.lanes_side, engine.patches_ahead, engine.patches_behind, temporal_window)
        self.net = net
        self.engine = engine
        self.ruleset = engine.ruleset
        self.epsilon = float(epsilon)
        self.name = name or f"brain[{net.hidden or 'linear'}]"
        self.flat: FlatNet = flatten(net)
        tw = temporal_window
        net_inputs = net_input_size(engine.num_inputs, tw)
        self.gcfg = np.zeros(N_GCFG, dtype=np.int64)
        self.gcfg[G_RULESET] = RULESET_V1 if self.ruleset == "v1" else RULESET_V2
        self.gcfg[G_TW] = tw
        self.gcfg[G_NUM_STATES] = engine.num_inputs
        self.gcfg[G_NET_INPUTS] = net_inputs
        self.gcfg[G_WINDOW] = max(tw, 2)
        self.gcfg[G_N_BRAINS] = MAX_BRAINS
        self.gflt = np.array([self.epsilon], dtype=np.float64)
        self.netin = np.zeros(net_inputs)
        self.buf = np.zeros((2, max(self.flat.max_width, net_inputs)))
        self.stream_state: int | None = None
        self.reset(n_worlds)

    @classmethod
    def of_settings(
        cls,
        net: ConvNet,
        settings: Settings,
        ruleset: str | None = None,
        *,
        other_agents: int | None = None,
        epsilon: float | None = None,
        n_worlds: int = 1,
        name: str | None = None,
    ) -> BrainPolicy:
        """The brain of a net file: its engine (``engine_config``), its temporal window and ε_test (net.js defaults)."""
        brain = settings.filled()
        eps = brain.epsilon_test_time if epsilon is None else epsilon
        engine = engine_config(settings, ruleset, other_agents)
        return cls(net, engine, brain.temporal_window, eps, n_worlds=n_worlds, name=name)

    compiled = staticmethod(brain_policy)

    def run_world(self, sim: Simulator, max_runs: int) -> None:
        """``sim.protocols.evaluate``'s driver hook: world 0 for up to ``max_runs`` runs in the cached ``run_brain``."""
        obs = np.zeros(sim.config.num_inputs)
        run_brain(
            sim.cars, sim.grid, sim.fs, sim.ints, sim.mrand, sim.cfg, 0, self.pstate, obs,
            sim.scores, sim.ego_scores, sim.run_seeds, max_runs,
        )  # fmt: skip

    def reset(self, n_worlds: int = 1, caches: np.ndarray | None = None) -> None:
        """Fresh brains (no history, ``forward_passes = 0``) for ``n_worlds`` worlds."""
        window = int(self.gcfg[G_WINDOW])
        ns = int(self.gcfg[G_NUM_STATES])
        self.n_worlds = n_worlds
        self.wstate = np.zeros((n_worlds, N_WSTATE), dtype=np.int64)
        if caches is not None:
            self.wstate[:, W_CACHE] = caches
        self.bstate = np.zeros((n_worlds, MAX_BRAINS, N_BSTATE), dtype=np.int64)
        self.bstate[:, :, B_HEAD] = window - 1
        self.states = np.zeros((n_worlds, MAX_BRAINS, window, ns))
        self.actions = np.zeros((n_worlds, MAX_BRAINS, window), dtype=np.int64)

    @property
    def pstate(self) -> tuple[np.ndarray, ...]:
        return (
            self.flat.codes,
            self.flat.params,
            self.gcfg,
            self.gflt,
            self.wstate,
            self.bstate,
            self.states,
            self.actions,
            self.netin,
            self.buf,
        )

    def prepare(
        self,
        protocol: str,
        seed: int | None = None,
        runs: int | None = None,
        gauss_cache: int = 0,
        engine_load: bool = True,
    ) -> int | None:
        """Reset the brains as the protocol's harness builds them; returns ``stream_state`` for ``evaluate``.

        ``gauss_cache`` is convnetjs's global Gaussian cache flag before the brain is built: 0 in a
        fresh process (evaluate.js, a fresh web worker); a harness that evaluates several nets in
        one process inherits the previous evaluation's final flag (``final_gauss_cache``).

        * v2-official: ``mulberry32(seed)``, brain built → the state before the engine load;
        * v2-heldout: as v2-official from ``mulberry32(1)`` (its ``seed`` moves the runs, not the stream);
        * v1-original: ``mulberry32(seed)``, brain built, v1 engine loaded (60 draws) → the state
          before ``doEvalRun``. ``engine_load=False``: no load draws, as in the harness of
          ``learner_scores.json``, whose engine existed before ``Math.random`` was seeded (its
          recorded scores reproduce only that way);
        * v1-distribution: brain built from ``mulberry32(seed)`` (only its Gaussian cache survives the
          per-run re-seeding) → None;
        * custom: world i's brain as if built from ``mulberry32(seed + i)`` → None.
        """
        if protocol not in PROTOCOLS:
            raise ConfigError(f"protocol: '{protocol}' is not a protocol; use one of {', '.join(PROTOCOLS)}")
        proto = PROTOCOLS[protocol]
        seed = proto.seed if seed is None else int(seed)
        if protocol == CUSTOM:
            n = proto.runs if runs is None else runs
            caches = np.array([build_draws(self.net, seed + i, gauss_cache)[1] for i in range(n)], dtype=np.int64)
            self.reset(n, caches)
            self.stream_state = None
            return None
        stream = V2_OFFICIAL_STREAM_SEED if protocol == V2_HELDOUT else seed
        built, cache, _draws = build_draws(self.net, stream, gauss_cache)
        self.reset(1, np.array([cache], dtype=np.int64))
        state: int | None = built
        if protocol == V1_ORIGINAL and engine_load:
            state = mulberry32_advance(built, V1_LOAD_DRAWS)
        elif protocol == V1_DISTRIBUTION:
            state = None
        self.stream_state = state
        return state

    @property
    def greedy_actions(self) -> np.ndarray:
        """How often each action (0–4) was the net's greedy choice since the last reset, over every world and
        brain (ε_test's random moves and the warm-up's not counted): one nonzero entry means a constant policy."""
        return self.wstate[:, W_GREEDY:].sum(axis=0)

    @property
    def final_gauss_cache(self) -> int:
        """World 0's Gaussian cache flag now (after an evaluation: what the next build in that process sees)."""
        return int(self.wstate[0, W_CACHE])

    def _grow(self, n_worlds: int) -> None:
        old = (self.wstate, self.bstate, self.states, self.actions)
        n_old = self.n_worlds
        self.reset(n_worlds)
        for new, prev in zip((self.wstate, self.bstate, self.states, self.actions), old, strict=True):
            new[:n_old] = prev

    def __call__(self, obs: Any) -> np.ndarray:
        """Batched decisions: one row per (world, car); draws from each world's Math.random stream."""
        n = len(obs)
        out = np.zeros(n, dtype=np.int64)
        if n == 0:
            return out
        worlds = np.ascontiguousarray(obs.world, dtype=np.int64)
        if int(worlds.max()) >= self.n_worlds:
            self._grow(int(worlds.max()) + 1)
        inputs = np.ascontiguousarray(obs.inputs, dtype=np.float64)
        cars = np.ascontiguousarray(obs.car, dtype=np.int64)
        _decide_rows(inputs, cars, worlds, obs.mrand, self.pstate, out)
        return out


def engine_config(settings: Settings, ruleset: str | None = None, other_agents: int | None = None) -> EngineConfig:
    """The simulator configuration a net file is evaluated in: its engine unless ``ruleset`` says otherwise, and
    in v2 ``other_agents`` or else the file's otherAgents (0 when unset), capped at 10 as the engine does
    from its first reset (spec v2 §8.1). v1 takes no other agents (``EngineConfig`` says so if asked)."""
    ruleset = ruleset or settings.engine
    if ruleset == "v1":
        other_agents = other_agents or 0
    else:
        other_agents = min(other_agents if other_agents is not None else (settings.other_agents or 0), 10)
    return EngineConfig(
        ruleset=ruleset,
        lanes_side=settings.lanes_side,
        patches_ahead=settings.patches_ahead,
        patches_behind=settings.patches_behind,
        other_agents=other_agents,
    )


def resolve_ruleset(settings: Settings, protocol: str, ruleset: str | None) -> str:
    """Explicit ruleset, else the protocol's, else the net's own engine."""
    if ruleset:
        return ruleset
    proto = PROTOCOLS.get(protocol)
    if proto is not None and proto.ruleset is not None:
        return proto.ruleset
    return settings.engine


def evaluate_net(
    net: ConvNet,
    settings: Settings,
    protocol: str = V2_OFFICIAL,
    *,
    ruleset: str | None = None,
    seed: int | None = None,
    other_agents: int | None = None,
    runs: int | None = None,
    frames: int | None = None,
    threads: int | None = None,
    epsilon: float | None = None,
    progress: ProgressFn | None = None,
    name: str | None = None,
    gauss_cache: int = 0,
    engine_load: bool = True,
) -> EvalResult:
    """Evaluate a net file's trained net exactly as the original harness would (per-run scores in run order).

    ``protocol``: v2-official, v2-heldout, v1-original, v1-distribution or custom (``sim.protocols``);
    ``ruleset`` defaults to the protocol's (custom: the net's engine); ``other_agents`` (v2)
    defaults to the net's ``otherAgents`` (0 when unset); the temporal window and ε_test are the
    file's, or deepqlearn's defaults. The rest as ``evaluate_brain``.
    """
    ruleset = resolve_ruleset(settings, protocol, ruleset)
    brain = settings.filled()
    return evaluate_brain(
        net,
        engine_config(settings, ruleset, other_agents),
        brain.temporal_window,
        brain.epsilon_test_time if epsilon is None else epsilon,
        protocol,
        seed=seed,
        runs=runs,
        frames=frames,
        threads=threads,
        progress=progress,
        name=name,
        gauss_cache=gauss_cache,
        engine_load=engine_load,
    )


def _prepared(
    net: ConvNet,
    engine: EngineConfig,
    temporal_window: int,
    epsilon: float,
    protocol: str,
    seed: int | None,
    runs: int | None,
    name: str | None,
    gauss_cache: int,
    engine_load: bool,
) -> tuple[BrainPolicy, int | None]:
    """The brain an evaluation drives, built as the protocol's harness builds it, and the ``Math.random`` state
    the protocol starts from (``BrainPolicy.prepare``)."""
    proto = PROTOCOLS.get(protocol)  # (sim.protocols.evaluate refuses a protocol of the other engine)
    policy = BrainPolicy(net, engine, temporal_window, epsilon, name=name)
    n_runs = runs if runs is not None else (proto.runs if proto is not None else None)
    return policy, policy.prepare(protocol, seed, n_runs, gauss_cache, engine_load)


def evaluate_brain(
    net: ConvNet,
    engine: EngineConfig,
    temporal_window: int,
    epsilon: float,
    protocol: str = V2_OFFICIAL,
    *,
    seed: int | None = None,
    runs: int | None = None,
    frames: int | None = None,
    threads: int | None = None,
    progress: ProgressFn | None = None,
    name: str | None = None,
    gauss_cache: int = 0,
    engine_load: bool = True,
    greedy_actions: np.ndarray | None = None,
) -> EvalResult:
    """Evaluate a trained net in ``engine`` with the deepqlearn brain (``temporal_window``, ε = ``epsilon``).

    ``gauss_cache``: convnetjs's Gaussian cache flag before the brain build (0 = fresh process, see
    ``BrainPolicy.prepare``); ``engine_load``: v1-original only, whether the engine's 60 construction
    draws follow the brain build (evaluate.js: yes; the learner_scores.json harness: no).
    ``greedy_actions`` (5 int64s), when given, receives ``BrainPolicy.greedy_actions`` of the evaluation.
    """
    policy, stream_state = _prepared(net, engine, temporal_window, epsilon, protocol, seed, runs, name,
                                     gauss_cache, engine_load)  # fmt: skip
    result = evaluate(
        engine,
        policy,
        protocol,
        seed=seed,
        runs=runs,
        frames=frames,
        threads=threads if protocol not in SEQUENTIAL_PROTOCOLS else None,  # one world: numba threads unused
        stream_state=stream_state,
        policy_name=policy.name,
        progress=progress,
    )
    if greedy_actions is not None:
        greedy_actions[:] = policy.greedy_actions
    return result


def brain_evaluation(
    net: ConvNet,
    engine: EngineConfig,
    temporal_window: int,
    epsilon: float,
    protocol: str = V2_OFFICIAL,
    *,
    seed: int | None = None,
    runs: int | None = None,
    name: str | None = None,
    gauss_cache: int = 0,
    engine_load: bool = True,
) -> SequentialEvaluation:
    """``evaluate_brain``'s evaluation, pausable between runs (``sim.protocols.SequentialEvaluation``; its
    ``policy`` is the ``BrainPolicy``, whose ``greedy_actions`` count the runs done so far). Sequential
    protocols only (v2-official, v2-heldout, v1-original); seeded exactly as ``evaluate_brain`` seeds them."""
    policy, stream_state = _prepared(net, engine, temporal_window, epsilon, protocol, seed, runs, name,
                                     gauss_cache, engine_load)  # fmt: skip
    return SequentialEvaluation(engine, policy, protocol, seed=seed, runs=runs, stream_state=stream_state,
                                policy_name=policy.name)  # fmt: skip


__all__ = [
    "BrainPolicy",
    "brain_evaluation",
    "brain_policy",
    "engine_config",
    "evaluate_brain",
    "evaluate_net",
    "resolve_ruleset",
]
