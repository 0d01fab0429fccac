"""The DeepTraffic training protocol: ``train`` drives one world through the runs, records the curve.

Randomness of the original (``train(…, stream="original")``): the original learner draws from
``Math.random`` (shared with v1's traffic; in v2 also feeding the training-mode seeds) — the
weight-initialisation Gaussians, and per decision the replacement slot, the replay indices, ``rf``,
the random actions and the discarded Gaussians of every ``new Vol`` (spec §10.6).
``js_learner.OriginalStream`` supplies exactly those draws in that order, so in float64 this learner
makes the original's decisions and ends its runs with the original's scores (learner_scores*.json,
``tests/test_js_learner.py``). The default
(``stream="independent"``) uses independent seeded generators and no Vol draws: ~25 % faster,
the same learner statistically.

Training protocol (``train``; train.js / train_webworker.js, spec §9, v2 §12): one world,
``⌈numRuns⌉`` runs of ``⌈totalFrames/numRuns⌉`` frames (``config.schedule``), the brain persisting
across runs. In v2 with ``other_agents > 0`` the agents act as the original's frozen brain copies
do during training (v2 §8.3): action 0 while the ego has made ≤ tw decisions (the load-time copies'
warm-up), then uniformly random (the copies keep ``age = tw + 1``, so their ε is 1 for any
burnin > tw + 1; for burnin ≤ tw + 1 they act greedily with probability 1 − ε on a frozen snapshot,
as the copies would). The simulator applies the shared-action rules itself.

Randomness (independent stream): everything derives from ``np.random.SeedSequence(seed)`` — a numpy
generator for the learner's draws, one for the agents, a torch generator for initialisation and
dropout masks, and the simulator's ``Math.random`` state; no global RNG is touched.

Parity with the JS learner (``bench/learner_parity.py``; network_basic, seeds 1–8, evaluated like
learner_scores*.json): with the original stream in float64, the same 8 runs as the original in
both engines (v1 median 70.41, 1 collapsed; v2 66.30, none); v1 in float32 the runs follow the
original's for a while and then part (median 70.89, none collapsed); independent stream, v2:
median 66.20, no collapsed seed. The
original itself (the replica over seeds 1–93) has a median of 69.4 with 6 of 93 seeds collapsed;
the independent-stream learner gives 68.8 (float32) / 69.1 (float64) over 56 seeds.

Speed: one decision = one simulator call + one ``learn`` call. The batch update is a hand-written
forward/backward over preallocated buffers (``Kernel``; the s₀ and s₁ halves of the batch go
through the net as one 2B-row matrix), the greedy action uses numpy views of the same parameter
memory (cheaper than torch dispatch for one row), scalar draws come from pre-drawn blocks, and
the simulator is stepped through its public single-world fast path (``Simulator.step_single``).
Other agents acting at random (ε = 1, the usual v2 case) are answered inside the simulator from
actions drawn a block ahead (``Simulator.step_single_agents``, the same draws in the same order):
ten agents cost one Python call per ego decision instead of eleven (network_basic with 10 agents:
16,900 it/s against 13,000; a linear 270k-iteration adagrad net: 13.8 s against 18.2).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np
import torch

from autotune.convnet import spec, torch_bridge
from autotune.learner.agents import TrainingAgents
from autotune.learner.brain import DeepQLearner, DivergedError
from autotune.learner.config import ConfigError, TrainConfig
from autotune.learner.js_learner import OriginalStream
from autotune.learner.quick_eval import QUICK_EVAL_SEED, quick_evaluate
from autotune.runtime import process_configured
from sim.layout import I_RUNS_DONE
from sim.simulator import Simulator

__all__ = ["StopTraining", "CurvePoint", "TrainResult", "Reporter", "train"]


class StopTraining(Exception):
    """Raise from a reporter (or return True from it) to end training early; ``train`` returns normally.

    ``TrainResult.stopped`` is then True and ``stop_reason`` holds the message. Any other exception
    a reporter raises (e.g. ``optuna.TrialPruned``) propagates out of ``train`` unchanged.
    """


# --------------------------------------------------------------------------------------------
# training protocol
# --------------------------------------------------------------------------------------------


class CurvePoint(NamedTuple):
    """One learning-curve point (reported every ``1/report_points`` of training)."""

    frames: int
    """Training frames simulated so far."""
    quick_score: float | None
    """Mean run score (mph) of the quick evaluation of the greedy net (None when disabled)."""
    mean_reward: float
    """Mean ego reward per decision since the previous point ((mph̄ − 40)·0.075 per interval)."""
    loss: float
    """Mean sampled TD loss ½(Q − y)² since the previous point (NaN before learning starts)."""
    decisions: int
    """Ego decisions so far (= brain age)."""
    epsilon: float
    """ε of the latest decision."""
    wall_seconds: float
    """Wall time since training started (quick evaluations included)."""


@dataclasses.dataclass
class TrainResult:
    """What ``train`` returns. ``module`` is the trained ``torch_bridge.ConvNetModule`` (eval mode)."""

    config: TrainConfig
    seed: int
    module: Any
    layers: tuple
    curve: list[CurvePoint]
    frames: int
    """Frames simulated (all runs, partial last run included)."""
    decisions: int
    """Ego decisions (learn calls)."""
    agent_decisions: int
    updates: int
    """Batch updates made (one per decision once learning started)."""
    wall_seconds: float
    train_seconds: float
    """Wall time without the quick evaluations."""
    train_cpu_seconds: float
    """Process CPU time without the quick evaluations (robust to a busy machine; single-threaded run)."""
    runs_completed: int
    training_run_scores: list[float]
    """Scores of the completed training runs (what train.js's doEvalRun computes)."""
    final_epsilon: float
    experience_size_final: int
    final_gauss_cache: int | None = None
    """``stream="original"``: convnetjs's Gaussian cache flag at the end (what a brain built next in the
    same process starts from); None otherwise."""
    diverged: bool = False
    diverged_reason: str | None = None
    stopped: bool = False
    stop_reason: str | None = None
    weight_change: float = 0.0
    """‖θ_end − θ_0‖ / ‖θ_0‖ over every weight and bias: how far training moved the net from its initialisation
    (0 when no update was made). Nets that learn to drive move by percents in 10k decisions; a learning rate
    too small to matter leaves them within a fraction of a per mille, whatever the score of the initial net."""

    @property
    def iterations_per_second(self) -> float:
        """Training throughput in trainIterations (ego decisions) per second, quick evaluations excluded."""
        return self.decisions / self.train_seconds if self.train_seconds > 0 else math.inf

    @property
    def frames_per_second(self) -> float:
        return self.frames / self.train_seconds if self.train_seconds > 0 else math.inf

    def convnet(self) -> spec.ConvNet:
        """The trained net as a float64 ``ConvNet`` (for export and exact evaluation)."""
        return torch_bridge.from_torch(self.module, self.layers)

    def summary(self) -> dict[str, Any]:
        """JSON-ready counters and status (no weights, no curve)."""
        return {
            "seed": self.seed,
            "frames": self.frames,
            "decisions": self.decisions,
            "agent_decisions": self.agent_decisions,
            "updates": self.updates,
            "wall_seconds": self.wall_seconds,
            "train_seconds": self.train_seconds,
            "train_cpu_seconds": self.train_cpu_seconds,
            "iterations_per_second": self.iterations_per_second,
            "frames_per_second": self.frames_per_second,
            "runs_completed": self.runs_completed,
            "training_run_scores": self.training_run_scores,
            "final_epsilon": self.final_epsilon,
            "experience_size_final": self.experience_size_final,
            "final_gauss_cache": self.final_gauss_cache,
            "diverged": self.diverged,
            "diverged_reason": self.diverged_reason,
            "stopped": self.stopped,
            "stop_reason": self.stop_reason,
            "weight_change": self.weight_change,
        }


Reporter = Callable[[int, int, float], Any]
"""``reporter(step_index, frames_done, quick_score)`` → truthy to stop (or raise ``StopTraining``)."""


@dataclasses.dataclass(frozen=True)
class _Seeds:
    """Every random source of one training run, derived from its seed (nothing global)."""

    seed: int
    """The run's seed (``train``'s argument)."""
    brain: np.random.SeedSequence
    """The learner's draws and its torch generator (``DeepQLearner``)."""
    agents: np.random.SeedSequence
    """The v2 training agents' draws."""
    sim_state: int
    """The engine's ``Math.random`` state (independent stream)."""
    eval: np.random.SeedSequence
    """The quick evaluations' exploration draws."""
    original: OriginalStream | None
    """``stream="original"``: the original harness's one ``Math.random`` stream, else None."""

    @classmethod
    def derive(cls, seed: int, stream: str) -> _Seeds:
        s_brain, s_agents, s_sim, s_eval = np.random.SeedSequence(int(seed)).spawn(4)
        sim_state = int(s_sim.generate_state(1, np.uint32)[0])
        original = OriginalStream(seed) if stream == "original" else None
        return cls(int(seed), s_brain, s_agents, sim_state, s_eval, original)


@dataclasses.dataclass(frozen=True)
class _Reporting:
    """How a training run reports: the curve's schedule, its quick evaluations, the reporter, the progress bar."""

    points: int
    """Curve points, one every ``1/points`` of the ego decisions."""
    quick_eval: bool
    """Whether each point carries a quick score (``quick_evaluate``)."""
    runs: int
    """Quick-evaluation runs (independent custom-protocol worlds)."""
    frames: int
    """Frames per quick-evaluation run."""
    seed: int
    """Quick-evaluation seed (world i ↦ seed + i, the same for every trial)."""
    reporter: Reporter | None
    """``reporter(k, frames_done, quick_score)`` at every point; truthy or ``StopTraining`` stops training."""
    progress: Callable[[int, int], None] | None
    """``progress(frames_done, total_frames)`` about every 1 % of the decisions, at least every 1,000."""


def train(
    config: TrainConfig,
    seed: int,
    reporter: Reporter | None = None,
    *,
    report_points: int = 10,
    quick_eval: bool = True,
    quick_eval_runs: int = 20,
    quick_eval_frames: int = 2000,
    quick_eval_seed: int = QUICK_EVAL_SEED,
    progress: Callable[[int, int], None] | None = None,
    torch_threads: int | None = None,
    stream: str = "independent",
    init_net: spec.ConvNet | None = None,
) -> TrainResult:
    """Train ``config`` with the DeepTraffic training protocol from ``seed``.

    ``stream``: ``"independent"`` (default) derives the engine's ``Math.random`` state, the
    learner's draws and the initialisation from ``np.random.SeedSequence(seed)``;
    ``"original"`` is the original harness's randomness: ``Math.random := mulberry32(seed)``, the
    weights drawn from it by convnetjs's Gaussian routine, then every learner draw from that one
    stream (``js_learner.OriginalStream``) — in v1 (train.js) shared with the traffic, in v2 (the
    training worker) after the engine load and the training-mode seeding, whose Park–Miller run
    seeds it also provides. With ``dtype="float64"`` that reproduces the original's training runs
    (learner_scores*.json); dropout masks, if any, still come from torch's generator.

    Every ``1/report_points`` of the ego decisions a ``CurvePoint`` is recorded — with a quick score
    (``quick_evaluate``: ``quick_eval_runs`` × ``quick_eval_frames`` custom-protocol runs of the
    current greedy net, seeds ``quick_eval_seed + i``, the same for every trial) unless
    ``quick_eval`` is False — and ``reporter(k, frames_done, quick_score)`` is called with
    k = 0 … report_points − 1. The reporter stops training by returning True or raising
    ``StopTraining``; other exceptions propagate. A diverging net (non-finite Q or loss) ends
    training with ``result.diverged`` set. ``progress(frames_done, total_frames)`` is called about
    every 1 % of the decisions and at least every 1,000 (progress bars, wall-time limits).

    ``init_net``: train on from this net's weights (a page that loaded them with ``value_net.fromJSON`` before
    training; ``DeepQLearner``) instead of fresh ones; its layers must be the config's (``ConfigError``
    otherwise). Every draw of the run is the one it makes without ``init_net``; ``weight_change`` is measured
    from the loaded weights.

    Process settings: after ``autotune.configure_process`` (the CLI, a worker) ``train`` leaves
    torch's threads and denormal flushing as the process set them. ``torch_threads`` (or a process
    nobody configured, then with 1 thread) sets them for this call only: that many intra-op
    threads and denormal flushing on, both restored afterwards.
    """
    if reporter is not None and not quick_eval:
        raise ValueError("reporter: needs quick_eval=True (the reporter receives the quick score)")
    if report_points < 1:
        raise ValueError(f"report_points: must be ≥ 1, got {report_points}")
    if stream not in ("independent", "original"):
        raise ConfigError(f"stream: '{stream}' is not a stream; use independent or original")
    seeds = _Seeds.derive(seed, stream)
    reporting = _Reporting(
        points=report_points,
        quick_eval=quick_eval,
        runs=quick_eval_runs,
        frames=quick_eval_frames,
        seed=quick_eval_seed,
        reporter=reporter,
        progress=progress,
    )
    if torch_threads is None and not process_configured():
        torch_threads = 1
    old_threads = torch.get_num_threads()
    if torch_threads is not None:
        torch.set_num_threads(torch_threads)
        torch.set_flush_denormal(True)  # tiny activations must not hit the slow denormal path (reset to off after)
    try:
        with torch.no_grad():
            return _train(config, seeds, reporting, init_net)
    finally:
        if torch_threads is not None:
            torch.set_num_threads(old_threads)
            torch.set_flush_denormal(False)


def _train(
    config: TrainConfig, seeds: _Seeds, reporting: _Reporting, init_net: spec.ConvNet | None = None
) -> TrainResult:
    t0 = time.perf_counter()
    c0 = time.process_time()
    seed, original, progress = seeds.seed, seeds.original, reporting.progress
    brain = DeepQLearner(config, seeds.brain, stream=original, init_net=init_net)
    initial = _flat_params(brain.module)
    eval_rng = np.random.default_rng(seeds.eval)
    runs, frames_per_run = config.schedule
    curve: list[CurvePoint] = []
    eval_seconds = 0.0
    eval_cpu = 0.0
    result: dict[str, Any] = dict(diverged=False, diverged_reason=None, stopped=False, stop_reason=None)
    agent_decisions = 0
    sim: Simulator | None = None
    if runs == 0:
        return _result(config, seed, brain, initial, curve, None, 0, (t0, c0), (eval_seconds, eval_cpu), result)

    sim = Simulator(config.engine_config, 1, frames_per_run, runs)
    start_state = original.state if original is not None else seeds.sim_state
    if config.ruleset == "v2":
        # engine load, then training mode: brain.reset_seed and one reset_seed per agent copy existing at load
        sim.seed_training(start_state, brain_draws=1 + min(config.other_agents, 9))
    else:
        sim.seed_stream(start_state)  # train.js: the runs start right after the brain build
    if original is not None:
        original.attach(sim.mrand)
    total_decisions = config.ego_decisions
    total_frames = runs * frames_per_run
    marks = [max(1, round(total_decisions * (k + 1) / reporting.points)) for k in range(reporting.points)]
    progress_every = max(1, min(1000, total_decisions // 100))  # wall-time limits need a beat on big nets too
    agents = TrainingAgents(config, brain, seeds.agents, original) if config.other_agents > 0 else None

    learn = brain.learn
    step = sim.step_single  # the simulator's public single-world fast path
    blind = agents is not None and agents.blind  # agents acting at random: answered inside the simulator
    tw = config.temporal_window
    inputs = sim.obs_inputs[0]  # views, updated in place by every step
    reward_arr = sim.obs_reward
    decisions = 0
    k_mark = 0
    next_mark = marks[0]
    next_progress = progress_every
    car = sim.start_single()
    try:
        while car >= 0:
            if car == 0:
                action = learn(inputs, float(reward_arr[0]))
                decisions += 1
                if blind and brain.forward_passes > tw:  # the agents' decisions up to the ego's next, compiled
                    car, answered = agents.step_to_ego(sim, action)  # type: ignore[union-attr]
                    agent_decisions += answered
                else:
                    car = step(action)
                if decisions >= next_mark:
                    te = time.perf_counter()
                    ce = time.process_time()
                    stop = _report(k_mark, brain, sim, config, curve, reporting, eval_rng, t0)
                    eval_seconds += time.perf_counter() - te
                    eval_cpu += time.process_time() - ce
                    k_mark += 1
                    next_mark = marks[k_mark] if k_mark < len(marks) else total_decisions + 1
                    if stop is not None:
                        result["stopped"] = True
                        result["stop_reason"] = stop
                        break
                if progress is not None and decisions >= next_progress:
                    next_progress += progress_every
                    progress(sim.frames_simulated, total_frames)
            else:
                agent_decisions += 1
                car = step(agents.act(car, inputs))  # type: ignore[union-attr]
    except DivergedError as exc:
        result["diverged"] = True
        result["diverged_reason"] = str(exc)
    if progress is not None:
        progress(sim.frames_simulated, total_frames)
    times = (t0, c0), (eval_seconds, eval_cpu)
    return _result(config, seed, brain, initial, curve, sim, agent_decisions, *times, result)


def _report(
    k: int,
    brain: DeepQLearner,
    sim: Simulator,
    config: TrainConfig,
    curve: list[CurvePoint],
    reporting: _Reporting,
    rng: np.random.Generator,
    t0: float,
) -> str | None:
    """Record a curve point, call the reporter; returns a stop reason or None."""
    score: float | None = None
    reporter = reporting.reporter
    if reporting.quick_eval:
        res = quick_evaluate(
            brain.module, config, runs=reporting.runs, frames=reporting.frames, seed=reporting.seed, rng=rng
        )
        score = res.mean
    mean_reward, loss = brain.take_stats()
    frames_done = sim.frames_simulated
    curve.append(
        CurvePoint(
            frames=frames_done,
            quick_score=score,
            mean_reward=mean_reward,
            loss=loss,
            decisions=brain.age,
            epsilon=brain.epsilon,
            wall_seconds=time.perf_counter() - t0,
        )
    )
    if reporter is None:
        return None
    try:
        verdict = reporter(k, frames_done, score)  # type: ignore[arg-type]
    except StopTraining as exc:
        return str(exc) or f"stopped by the reporter at report {k}"
    if verdict:
        return f"stopped by the reporter at report {k} (frames {frames_done})"
    return None


def _flat_params(module: Any) -> np.ndarray:
    """Every parameter of ``module`` as one float64 vector (a copy)."""
    return np.concatenate([p.detach().to("cpu", torch.float64).numpy().ravel() for p in module.parameters()])


def _relative_change(initial: np.ndarray, module: Any) -> float:
    """‖θ − θ_0‖ / ‖θ_0‖ of ``module``'s parameters against ``initial`` (``_flat_params`` before training)."""
    norm = float(np.linalg.norm(initial))
    moved = float(np.linalg.norm(_flat_params(module) - initial))
    return moved / norm if norm > 0 else (math.inf if moved > 0 else 0.0)


def _result(
    config: TrainConfig,
    seed: int,
    brain: DeepQLearner,
    initial: np.ndarray,
    curve: list[CurvePoint],
    sim: Simulator | None,
    agent_decisions: int,
    starts: tuple[float, float],
    eval_times: tuple[float, float],
    status: dict[str, Any],
) -> TrainResult:
    wall = time.perf_counter() - starts[0]
    cpu = time.process_time() - starts[1]
    brain.module.eval()
    if sim is not None:
        done = int(sim.ints[0, I_RUNS_DONE])
        scores = [float(s) for s in sim.scores[0, :done]]
        frames = sim.frames_simulated
    else:
        done, scores, frames = 0, [], 0
    return TrainResult(
        config=config,
        seed=int(seed),
        module=brain.module,
        layers=brain.layers,
        curve=curve,
        frames=frames,
        decisions=brain.forward_passes,
        agent_decisions=agent_decisions,
        updates=brain.updates,
        wall_seconds=wall,
        train_seconds=max(wall - eval_times[0], 1e-9),
        train_cpu_seconds=max(cpu - eval_times[1], 1e-9),
        runs_completed=done,
        training_run_scores=scores,
        final_epsilon=brain.epsilon,
        experience_size_final=brain.n_exp,
        final_gauss_cache=int(brain._stream.cache[0]) if brain._stream is not None else None,
        weight_change=_relative_change(initial, brain.module),
        **status,
    )
