"""Evaluation protocols, seeded as the reference data was, so scores compare digit for digit.

* ``v2-official`` (engine_spec_v2.md §11): ``Math.random := mulberry32(seed)`` (default 1) before
  a fresh engine load, then ``doEvalRun(500, 2000, true)``: run k uses Park–Miller seed k + 1 and
  is coupled to run k − 1 through ``reset()``. The site's number is the lexicographic
  ``sorted[250]`` of the per-run scores. Sequential by nature.
* ``v1-original`` (engine_spec.md §9): ``evaluate.js`` — ``Math.random := mulberry32(seed)``
  (default 2000), ``doEvalRun(10, 100000)`` in one stream, lexicographic ``sorted[5]``. Sequential.
* ``v1-distribution`` (engine_spec.md §13): 200 × 10,000 frames, run i seeded ``seed + i``
  (default 1000). Independent worlds for memoryless policies; one world re-seeded per run for
  policies with memory (a network's temporal window persists across runs, as in the reference).
* ``v2-heldout``: the ``v2-official`` harness (engine_spec_v2.md §11) — ``Math.random := mulberry32(1)``, a
  fresh engine load, 500 sequential runs coupled through ``reset()`` (§3.3), the agents' brain copies and every
  temporal window carried from run to run (§8.3) — on runs it never plays: run k uses Park–Miller seed
  ``seed + k + 1`` (default 10⁶; seed 0 is ``v2-official`` exactly). What a net's official score would have been
  on another draw of runs: ``custom`` starts every run in a fresh world, and a net with a temporal window scores
  there up to 12 mph apart from the same runs played officially.
* ``custom``: ``runs`` × ``frames`` as independent worlds, world i seeded ``seed + i`` (v2: its run
  uses Park–Miller seed ``seed + i``), stepped as one batch.

The sequential protocols call a policy's compiled twin inside the simulation loop when it has
one (``policy.compiled``/``policy.pstate``), or the policy's own compiled driver of the world when
it has one (the hook ``policy.run_world(sim, max_runs)``: a cached, specialised loop, e.g. a
trained net's brain); otherwise the policy is called from Python once per decision, which is exact
but slower. ``wall_seconds`` starts after the compiled functions on the path are loaded (or
compiled, on a cold cache), so it measures simulation, not numba.
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import time
from collections.abc import Callable, Iterator
from typing import Any

import numba
import numpy as np

from sim.config import ConfigError, EngineConfig
from sim.jsnumber import js_number_to_string
from sim.layout import I_RUNS_DONE
from sim.policies import BoundPolicy
from sim.rng import PM_MODULUS, mulberry32_advance
from sim.simulator import Observation, Simulator


@dataclasses.dataclass(frozen=True)
class Protocol:
    name: str
    ruleset: str | None  # None: either
    runs: int
    frames: int
    seed: int
    sequential: bool
    description: str


# protocol names: compare and pass these, never the strings
V2_OFFICIAL = "v2-official"
V2_HELDOUT = "v2-heldout"
V1_ORIGINAL = "v1-original"
V1_DISTRIBUTION = "v1-distribution"
CUSTOM = "custom"
OFFICIAL: dict[str, str] = {"v1": V1_ORIGINAL, "v2": V2_OFFICIAL}  # ruleset -> its official protocol (the site's score)

PROTOCOLS: dict[str, Protocol] = {
    p.name: p
    for p in (
        Protocol(V2_OFFICIAL, "v2", 500, 2000, 1, True, "site evaluation worker: 500 × 2,000, run k ↦ PM seed k+1"),
        Protocol(V2_HELDOUT, "v2", 500, 2000, 1_000_000, True, "site evaluation worker, runs k ↦ PM seed seed+k+1"),
        Protocol(V1_ORIGINAL, "v1", 10, 100_000, 2000, True, "evaluate.js: 10 × 100,000 in one Math.random stream"),
        Protocol(V1_DISTRIBUTION, "v1", 200, 10_000, 1000, False, "200 × 10,000, run i ↦ mulberry32(seed + i)"),
        Protocol(CUSTOM, None, 100, 2000, 0, False, "runs × frames as independent worlds, world i ↦ seed + i"),
    )
}


def site_median(scores: list[float] | np.ndarray) -> float:
    """The originals' "median": JS default sort (by string) then element ``runs/2`` (floored)."""
    values = [float(s) for s in scores]
    ordered = sorted(values, key=js_number_to_string)
    return ordered[len(ordered) // 2]


@dataclasses.dataclass
class EvalResult:
    """Per-run scores in run order plus the summary statistics users compare."""

    protocol: str
    ruleset: str
    policy: str
    seed: int
    runs: int
    frames: int
    other_agents: int
    scores: list[float]
    ego_scores: list[float]
    wall_seconds: float
    official_size: bool

    @property
    def median_site(self) -> float:
        return site_median(self.scores)

    @property
    def median(self) -> float:
        return float(np.median(self.scores))

    @property
    def mean(self) -> float:
        return float(np.mean(self.scores))

    @property
    def std(self) -> float:
        return float(np.std(self.scores, ddof=1)) if len(self.scores) > 1 else 0.0

    @property
    def ci95(self) -> list[float]:
        """Normal-approximation 95 % interval of the mean run score."""
        half = 1.96 * self.std / math.sqrt(len(self.scores))
        return [self.mean - half, self.mean + half]

    @property
    def frames_per_second(self) -> float:
        return self.runs * self.frames / self.wall_seconds if self.wall_seconds > 0 else float("inf")

    def to_json(self) -> dict[str, Any]:
        return {
            "protocol": self.protocol,
            "ruleset": self.ruleset,
            "policy": self.policy,
            "seed": self.seed,
            "runs": self.runs,
            "frames": self.frames,
            "other_agents": self.other_agents,
            "official_size": self.official_size,
            "median_site": self.median_site,
            "median": self.median,
            "mean": self.mean,
            "std": self.std,
            "ci95": self.ci95,
            "min": float(np.min(self.scores)),
            "max": float(np.max(self.scores)),
            "wall_seconds": self.wall_seconds,
            "frames_per_second": self.frames_per_second,
            "scores": self.scores,
            "ego_scores": self.ego_scores,
        }


ProgressFn = Callable[[int, int], None]  # (frames done, frames total)


@contextlib.contextmanager
def numba_threads(threads: int | None) -> Iterator[None]:
    """numba's parallel loops on ``threads`` threads inside the block, the previous count restored after.

    None: the count the process owner set (``autotune.configure_process``), untouched. Library code
    changes the process-wide setting only this way, so a call never leaves it changed.
    """
    if threads is None:
        yield
        return
    if threads < 1:
        raise ConfigError(f"threads: must be ≥ 1, got {threads}")
    old = numba.get_num_threads()
    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    try:
        yield
    finally:
        numba.set_num_threads(old)


def _resolve(config: EngineConfig, protocol: str, runs: int | None, frames: int | None) -> tuple[Protocol, int, int]:
    if protocol not in PROTOCOLS:
        raise ConfigError(f"protocol: '{protocol}' is not a protocol; use one of {', '.join(PROTOCOLS)}")
    proto = PROTOCOLS[protocol]
    if proto.ruleset is not None and proto.ruleset != config.ruleset:
        raise ConfigError(
            f"protocol: '{protocol}' is a {proto.ruleset} protocol but the ruleset is {config.ruleset}; "
            f"use --ruleset {proto.ruleset} or the custom protocol"
        )
    runs = proto.runs if runs is None else runs
    frames = proto.frames if frames is None else frames
    if runs < 1:
        raise ConfigError(f"runs: must be ≥ 1, got {runs}")
    if frames < 1:
        raise ConfigError(f"frames: must be ≥ 1, got {frames}")
    return proto, runs, frames


V2_OFFICIAL_STREAM_SEED = 1
"""The ``Math.random`` seed of the site's evaluation worker (``v2-official``'s default), which ``v2-heldout``
keeps: only its runs' Park–Miller seeds move."""


def heldout_counter(seed: int, runs: int) -> int:
    """``v2-heldout``'s run counter before its first run: ``seed``, checked so that every run's Park–Miller seed
    ``seed + k + 1`` is a valid one (below 2³¹ − 1)."""
    top = PM_MODULUS - 1 - runs
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= seed <= top:
        raise ConfigError(f"seed: v2-heldout's runs use Park–Miller seeds seed + 1 … seed + runs, so seed must be "
                          f"an integer in 0–{top:,} for {runs} runs, got {seed!r} (10⁶ is the default)")  # fmt: skip
    return int(seed)


def evaluate(
    config: EngineConfig,
    policy: Callable[[Observation], Any],
    protocol: str = V2_OFFICIAL,
    *,
    seed: int | None = None,
    runs: int | None = None,
    frames: int | None = None,
    threads: int | None = None,
    stream_state: int | None = None,
    policy_name: str | None = None,
    progress: ProgressFn | None = None,
) -> EvalResult:
    """Evaluate ``policy`` with a named protocol; per-run scores come back in run order.

    ``stream_state`` overrides the ``Math.random`` state the protocol starts from (default
    ``mulberry32(seed)``): a caller that consumed draws before the engine starts — building a
    convnetjs brain draws its weights from the same stream — passes the advanced state.
    ``threads``: numba threads of the batched protocols for this call only (``numba_threads``);
    None leaves the process's count.
    """
    with numba_threads(threads):
        return _evaluate(
            config, policy, protocol, seed=seed, runs=runs, frames=frames, stream_state=stream_state,
            policy_name=policy_name, progress=progress,
        )  # fmt: skip


def _evaluate(
    config: EngineConfig,
    policy: Callable[[Observation], Any],
    protocol: str,
    *,
    seed: int | None,
    runs: int | None,
    frames: int | None,
    stream_state: int | None,
    policy_name: str | None,
    progress: ProgressFn | None,
) -> EvalResult:
    proto, runs, frames = _resolve(config, protocol, runs, frames)
    seed = proto.seed if seed is None else seed
    name = policy_name or getattr(policy, "name", None) or getattr(policy, "__name__", type(policy).__name__)
    compiled = getattr(policy, "compiled", None)
    memoryless = not getattr(policy, "stateful", compiled is None)
    builtin = policy if isinstance(policy, BoundPolicy) else None  # runs entirely compiled
    sequential = proto.sequential or (protocol == V1_DISTRIBUTION and not memoryless)

    def make_sim(runs: int, frames: int) -> Simulator:
        if not sequential:
            sim = Simulator(config, runs, frames, 1)
            sim.seed_independent(seed)
            return sim
        return _sequential_sim(config, protocol, seed, runs, frames, stream_state)

    run_world = getattr(policy, "run_world", None)  # the policy's own (cached) compiled single-world driver
    python_driven = builtin is None and not (sequential and (compiled is not None or run_world is not None))
    # load (or compile) the compiled functions on the path before the clock starts, without calling
    # the policy, so timings measure simulation; a compiled twin passed as an argument cannot be
    # cached and compiles inside the clock
    if builtin is not None:
        builtin.run(make_sim(1 if sequential else min(runs, 16), 1))
    elif python_driven:
        make_sim(1 if sequential else min(runs, 16), 1).start()
    start = time.perf_counter()
    total = runs * frames
    sim = make_sim(runs, frames)

    if python_driven:
        _drive(sim, policy, progress, total)
    elif sequential:  # one world with the policy compiled inline, in chunks of runs for the progress bar
        _advance(sim, policy, runs, progress)
    else:  # a built-in over independent worlds, in chunks of worlds for the progress bar
        assert builtin is not None
        chunk = max(64, 4_000_000 // frames)
        for first in range(0, runs, chunk):
            builtin.run(sim, first, min(runs, first + chunk))
            if progress:
                progress(min(runs, first + chunk) * frames, total)

    wall = time.perf_counter() - start
    scores = sim.scores.reshape(-1).tolist()
    ego = sim.ego_scores.reshape(-1).tolist()
    return EvalResult(
        protocol=protocol,
        ruleset=config.ruleset,
        policy=str(name),
        seed=seed,
        runs=runs,
        frames=frames,
        other_agents=config.other_agents,
        scores=scores,
        ego_scores=ego,
        wall_seconds=wall,
        official_size=(runs == proto.runs and frames == proto.frames),
    )


def _sequential_sim(
    config: EngineConfig, protocol: str, seed: int, runs: int, frames: int, stream_state: int | None
) -> Simulator:
    """The one world of a sequential evaluation, seeded as the protocol's harness seeds it."""
    sim = Simulator(config, 1, frames, runs)
    if protocol == V1_DISTRIBUTION:
        sim.seed_per_run([seed + i for i in range(runs)])
    elif protocol == V2_HELDOUT:
        start = mulberry32_advance(V2_OFFICIAL_STREAM_SEED, 0) if stream_state is None else stream_state
        sim.seed_stream(start, run_counter=heldout_counter(seed, runs))
    else:
        sim.seed_stream(mulberry32_advance(seed, 0) if stream_state is None else stream_state)
    return sim


def _advance(sim: Simulator, policy: Any, until: int, progress: ProgressFn | None) -> None:
    """Drive a sequential world (policy compiled inline) until ``until`` runs are done, in chunks of runs.

    Everything a run hands the next — the world, the ``Math.random`` stream, the policy's ``pstate`` — lives in
    arrays that persist between calls, so where the chunks end changes no score."""
    frames = sim.frames_per_run
    total = sim.runs_per_world * frames
    chunk = max(1, 200_000 // frames)
    run_world = getattr(policy, "run_world", None)
    while not sim.done and int(sim.ints[0, I_RUNS_DONE]) < until:
        n = min(chunk, until - int(sim.ints[0, I_RUNS_DONE]))
        if isinstance(policy, BoundPolicy):
            policy.run(sim, max_runs=n)
        elif run_world is not None:
            run_world(sim, n)
        else:
            sim.run_compiled(policy.compiled, policy.pstate, max_runs=n)
        if progress:
            progress(int(sim.ints[0, I_RUNS_DONE]) * frames, total)


class SequentialEvaluation:
    """A sequential protocol's evaluation that pauses between runs: ``advance(n)`` drives n more runs,
    ``result()`` scores the runs done so far.

    A pause changes nothing (``_advance``): a result after k runs is exactly the whole evaluation's first k runs,
    and carrying on to the end gives exactly ``evaluate``'s result. So a caller can score several policies on a
    protocol's first runs and finish only the one it keeps, paying for the shared runs once (the search's ε_test
    screens finish the chosen screen as the official evaluation). Needs a policy the loop runs compiled
    (``compiled``/``pstate``, ``run_world`` or a built-in) and a sequential protocol (v2-official, v2-heldout,
    v1-original).
    """

    def __init__(
        self,
        config: EngineConfig,
        policy: Any,
        protocol: str = V2_OFFICIAL,
        *,
        seed: int | None = None,
        runs: int | None = None,
        frames: int | None = None,
        stream_state: int | None = None,
        policy_name: str | None = None,
    ) -> None:
        proto, runs, frames = _resolve(config, protocol, runs, frames)
        if not proto.sequential:
            sequential = ", ".join(p.name for p in PROTOCOLS.values() if p.sequential)
            raise ConfigError(f"protocol: '{protocol}' runs independent worlds; pausable evaluations are "
                              f"sequential ({sequential}): use evaluate()")  # fmt: skip
        compiled = isinstance(policy, BoundPolicy) or any(
            getattr(policy, a, None) is not None for a in ("run_world", "compiled")
        )
        if not compiled:
            raise ConfigError("policy: a pausable evaluation drives a compiled policy (compiled/pstate, run_world "
                              "or a built-in); evaluate() drives Python policies")  # fmt: skip
        self.protocol = protocol
        self.config = config
        self.policy = policy
        self.seed = proto.seed if seed is None else seed
        self.runs = runs
        self.frames = frames
        self.official_size = runs == proto.runs and frames == proto.frames
        self.name = str(policy_name or getattr(policy, "name", None) or type(policy).__name__)
        self.sim = _sequential_sim(config, protocol, self.seed, runs, frames, stream_state)
        self.wall_seconds = 0.0

    @property
    def runs_done(self) -> int:
        return int(self.sim.ints[0, I_RUNS_DONE])

    @property
    def done(self) -> bool:
        return self.sim.done

    def advance(self, runs: int | None = None, progress: ProgressFn | None = None) -> int:
        """Drive ``runs`` more runs (None: to the end; never past it); returns the runs done.
        ``progress(frames done, frames of the whole evaluation)`` as ``evaluate``'s."""
        if runs is not None and runs < 0:
            raise ConfigError(f"runs: must be ≥ 0, got {runs}")
        until = self.runs if runs is None else min(self.runs, self.runs_done + runs)
        start = time.perf_counter()
        _advance(self.sim, self.policy, until, progress)
        self.wall_seconds += time.perf_counter() - start
        return self.runs_done

    def result(self) -> EvalResult:
        """The runs done so far, scored (the whole evaluation's ``EvalResult`` once ``done``)."""
        n = self.runs_done
        if n == 0:
            raise RuntimeError("SequentialEvaluation.result(): no run done yet; advance() first")
        return EvalResult(
            protocol=self.protocol,
            ruleset=self.config.ruleset,
            policy=self.name,
            seed=self.seed,
            runs=n,
            frames=self.frames,
            other_agents=self.config.other_agents,
            scores=self.sim.scores.reshape(-1)[:n].tolist(),
            ego_scores=self.sim.ego_scores.reshape(-1)[:n].tolist(),
            wall_seconds=self.wall_seconds,
            official_size=self.official_size and n == self.runs,
        )


def _drive(sim: Simulator, policy: Callable[[Observation], Any], progress: ProgressFn | None, total: int) -> None:
    """Python-policy loop: one policy call per batch of pending decisions."""
    obs = sim.start()
    last = 0
    while obs is not None:
        obs = sim.step(policy(obs))
        if progress:
            done = sim.frames_simulated
            if done - last >= 200_000:
                progress(done, total)
                last = done
    if progress:
        progress(total, total)
