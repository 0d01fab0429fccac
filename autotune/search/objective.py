"""The trial objective: train one configuration from its seed, report the curve, score it officially.

``run_trial(task, report)`` is everything a trial does, with no Optuna and no Ray in it, so the
same function runs in a test, in a notebook and inside a Ray worker. The caller supplies
``report(step, frames, quick_score) -> prune?``: the driver turns it into ``trial.report`` +
``trial.should_prune`` on the far side of a Ray round trip; a test can pass a lambda.

How a trial ends (``TrialOutcome.state``):

* ``"complete"`` — trained to the end and scored with the ruleset's official protocol (exact; the
  value is the site's median for v2-official, the same statistic for v1-original); with a ladder's
  ``epsilon_test_grid`` each rung first chooses its net's ε_test (``choose_epsilon``) and is scored at it;
* ``"pruned"`` — the pruner said so at a report, the net diverged (non-finite Q or loss), a rung's
  policy is static (``prune_static``: one greedy action, or a score unchanged from the rung before), a rung's
  training left the net where it started (``min_weight_change``: it does not learn), or a
  wall-time limit passed — the trial's own (``timeout_s``) or the study's (``deadline``), checked
  about every 1 % of training and between chunks of the official evaluation; ``cause`` says which.
  A trial stopped by a limit keeps the rungs it finished and never reports a truncated score. A rung that
  cannot count is not scored officially (its record's score is None): a net that does not learn is known as
  soon as it is trained, and a static one from the greedy choices of its chosen ε_test screen (the official
  evaluation's first runs);
* ``"failed"`` — the objective raised; ``cause`` holds the traceback. (A worker that dies is the
  driver's business: it never gets to return an outcome.)
"""

from __future__ import annotations

import dataclasses
import math
import os
import socket
import time
import traceback
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from autotune.search import keys

__all__ = [
    "TrialTask", "TrialOutcome", "Report", "run_trial", "worker_id", "process_start", "process_alive",
    "COMPLETE", "PRUNED", "FAILED",
]  # fmt: skip

COMPLETE, PRUNED, FAILED = "complete", "pruned", "failed"

Report = Callable[[int, int, float], bool]
"""``report(step k, training frames so far, quick score)`` → True to prune the trial now."""


@dataclasses.dataclass(frozen=True)
class TrialTask:
    """Everything a worker needs to run one trial (plain data: it crosses a Ray call)."""

    number: int
    """Optuna trial number (for messages)."""
    config: dict[str, Any]
    """``TrainConfig.to_mapping()`` of the trial: the real values it trains with."""
    seed: int
    """The trial's training seed (all randomness of ``train`` derives from it)."""
    report_points: int = 10
    """Intermediate scores, at (k+1)/report_points of training."""
    quick_runs: int = 20
    """Runs per intermediate (quick) score."""
    quick_frames: int = 2000
    """Frames per quick run."""
    final_protocol: str = ""
    """Protocol of the final score; '' = the ruleset's official one."""
    timeout_s: float | None = None
    """Wall-time limit of the whole trial [s] (training + evaluations); None: none."""
    rungs: tuple[int, ...] = ()
    """Budget ladder [iterations] up to the trial's top rung (``autotune.search.ladder``): rung r is a fresh,
    complete training at rungs[r] from ``rung_seed``, scored officially and reported at step rungs[r] / rungs[0];
    () = one training at the config's own length with quick scores reported along it."""
    reseed_rungs: bool = False
    """Train each rung below the top from a seed of its own (``ladder.rung_seed``; ``[ladder] reseed``); the top
    rung, and every rung when False, trains from ``seed``."""
    deadline: float | None = None
    """The study's end (``time.time()`` epoch seconds): a trial still running then stops, PRUNED; None: none."""
    prune_static: bool = False
    """Prune a ladder trial at a rung whose policy is static (``static_policy``): one greedy action, or the same
    official score as the rung before. With ``epsilon_test_grid`` the greedy choices are judged on the chosen
    screen (the official evaluation's first runs at its ε_test), and a net static there is pruned unscored."""
    min_weight_change: float = 0.0
    """Prune a ladder trial at a rung whose training moved the net's weights less than this fraction of their norm
    from the initialisation (``TrainResult.weight_change``): its net is kept but not scored (a score would measure
    the initial weights' luck, and never made a study's peak) nor reported to the pruner; 0 = never."""
    epsilon_test_grid: tuple[float, ...] = ()
    """Ladder trials: choose each rung's ε_test from these values (``choose_epsilon``) instead of the config's:
    screened on the protocol's first ``epsilon_test_screen_runs`` runs, the best scored officially; () = the
    config's ε_test (race runs, replays: a configuration is measured with its own)."""
    epsilon_test_screen_runs: tuple[int, ...] = (50, 100)
    """Runs of each stage of the ε_test screens (a prefix of the official protocol): every value on the first, the
    better half on to the next (``autotune.screen_epsilons``)."""
    init_net: str | None = None
    """convnetjs Net JSON of a trained net to train on from (a refinement run, ``[study] refine_share``: the page
    that loads weights with ``value_net.fromJSON`` and trains on); None: fresh weights from the seed."""
    evaluate_only: bool = False
    """Score ``init_net`` as it is, officially at the config's ε_test, training nothing (a weight soup,
    ``autotune.search.soup``)."""


@dataclasses.dataclass
class TrialOutcome:
    """How a trial ended and the record the driver stores (user attrs of the contract's "Trial records")."""

    number: int
    state: str
    """``COMPLETE``, ``PRUNED`` or ``FAILED``."""
    value: float | None
    """The official score [mph] (complete trials only)."""
    cause: str | None
    """Why the trial was pruned or failed (None when complete)."""
    attrs: dict[str, Any]
    """JSON-ready user attrs: config, settings, seed, curve, sizes, frames, timings, official stats, worker."""
    net_json: str | None = None
    """convnetjs Net JSON text of the trained net (complete trials)."""
    net_js: str | None = None
    """A net.js for the DeepTraffic page with the weights (complete trials)."""
    rung_nets: dict[int, str] = dataclasses.field(default_factory=dict)
    """convnetjs Net JSON of every finished rung, by budget (ladder trials; kept when pruned too)."""
    cpu_seconds: float = 0.0
    """Process CPU time the trial used (training + evaluations), for utilisation figures."""
    wall_seconds: float = 0.0
    """Wall time of the trial inside the worker."""


class _TrialTimeout(Exception):
    """Raised from ``train``'s progress hook when the trial's wall-time limit has passed."""


def worker_id() -> str:
    """``host:pid`` of this process (stored with every trial it runs)."""
    return f"{socket.gethostname()}:{os.getpid()}"


def process_start(pid: int) -> float | None:
    """Start time of process ``pid`` (clock ticks since boot, from /proc), None if it does not exist.

    (pid, start) identifies a process for good: a recycled pid has a later start. Without /proc
    (not Linux) the start is 0.0 for any existing pid.
    """
    try:
        stat = Path(f"/proc/{int(pid)}/stat").read_text()
        return float(stat[stat.rindex(")") + 2 :].split()[19])  # field 22 of proc(5), after "pid (comm) "
    except FileNotFoundError:
        if Path("/proc/self/stat").exists():
            return None
    except (OSError, ValueError, IndexError):
        return None
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return None
    except PermissionError:
        pass
    return 0.0


def process_alive(pid: int, start: float | None) -> bool:
    """True when process ``pid`` exists and (``start`` given) is the one that started at ``start``."""
    now = process_start(pid)
    return now is not None and (start is None or now == start or now == 0.0)


def _finite(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


def run_trial(task: TrialTask, report: Report) -> TrialOutcome:
    """Train ``task``'s config from its seed, forwarding each quick score to ``report``; score it if it ends."""
    t0 = time.perf_counter()
    c0 = time.process_time()
    attrs: dict[str, Any] = {
        keys.SOURCE: keys.SOURCE_AUTOTUNE, keys.SEED: int(task.seed), keys.WORKER: worker_id(), keys.DIVERGED: False,
    }  # fmt: skip

    rung_nets: dict[int, str] = {}

    def finish(state: str, value: float | None, cause: str | None, **texts: str | None) -> TrialOutcome:
        if cause is not None:
            attrs[keys.CAUSE] = cause
        cpu, wall = time.process_time() - c0, time.perf_counter() - t0
        attrs.update({keys.TRIAL_CPU_SECONDS: cpu, keys.TRIAL_WALL_SECONDS: wall})  # busy time (overhead bench)
        return TrialOutcome(
            task.number, state, value, cause, attrs, texts.get("net_json"), texts.get("net_js"), dict(rung_nets),
            cpu_seconds=cpu, wall_seconds=wall,
        )  # fmt: skip

    try:
        if task.evaluate_only:
            return _run_soup(task, attrs, _Limits.of(task, t0), finish)
        if task.rungs:
            return _run_ladder(task, report, attrs, _Limits.of(task, t0), finish, rung_nets)
        return _run(task, report, attrs, t0, finish)
    except _TrialTimeout as exc:
        return finish(PRUNED, None, str(exc))
    except Exception as exc:  # the objective's own failure: a FAIL state with the traceback, never a silent zero
        tb = traceback.format_exc(limit=8)
        return finish(FAILED, None, f"{type(exc).__name__}: {exc}\n{tb}")


@dataclasses.dataclass(frozen=True)
class _Limits:
    """The trial's wall-time limits as one check: its own ``timeout_s`` and the study's ``deadline``."""

    trial_end: float
    """``time.perf_counter()`` at which the trial's own limit passes (inf: none)."""
    study_end: float
    """``time.time()`` at which the study's budget ends (inf: none)."""
    timeout_s: float | None

    @classmethod
    def of(cls, task: TrialTask, t0: float) -> _Limits:
        return cls(t0 + task.timeout_s if task.timeout_s else math.inf,
                   task.deadline if task.deadline else math.inf, task.timeout_s)  # fmt: skip

    def check(self, where: str) -> None:
        """Raise ``_TrialTimeout`` naming the limit and ``where`` once either has passed."""
        if time.perf_counter() > self.trial_end:
            raise _TrialTimeout(f"timeout: trial wall time exceeded trial_timeout_s = {self.timeout_s:g} s ({where})")
        if time.time() > self.study_end:
            raise _TrialTimeout(f"deadline: the study's time budget ended ({where})")


def _run_ladder(
    task: TrialTask,
    report: Report,
    attrs: dict[str, Any],
    limits: _Limits,
    finish: Callable[..., TrialOutcome],
    rung_nets: dict[int, str],
) -> TrialOutcome:
    """Climb the budget ladder: a fresh training per rung, each scored officially and reported at B_r/B_0."""
    import numpy

    from autotune import TrainConfig, dumps_net, evaluate_official, export_netjs, official_protocol, screen_epsilons
    from autotune.learner import train
    from autotune.search.ladder import rung_config, rung_seed
    from sim.policies import NUM_ACTIONS

    top = TrainConfig.from_mapping(task.config)
    protocol = task.final_protocol or official_protocol(top)
    rungs: list[dict[str, Any]] = []
    attrs.update({
        keys.CONFIG: top.to_mapping(), keys.SETTINGS: top.to_deepqlearn(), keys.INPUT_SIZE: top.net_inputs,
        keys.NUM_STATES: top.num_states, keys.PARAM_COUNT: top.param_count, keys.OFFICIAL_PROTOCOL: protocol,
        keys.LADDER: list(task.rungs), keys.RUNGS: rungs, keys.FRAMES_SIMULATED: 0,
    })  # fmt: skip
    if task.epsilon_test_grid:
        attrs[keys.EPSILON_SCREEN_RUNS] = int(task.epsilon_test_screen_runs[-1])  # the finalists' (each screen: 4th)
    value: float | None = None
    net_json = net_js = None
    for r, budget in enumerate(task.rungs):
        config = rung_config(top, budget)
        where = f"rung {r}, {budget:,} iterations"
        t_rung = time.perf_counter()
        limits.check(f"before {where}")

        def progress(done: int, total: int, where: str = where) -> None:
            limits.check(f"{where}: training at {done:,} of {total:,} frames")

        seed = rung_seed(task.seed, budget, task.rungs[-1], task.reseed_rungs)
        result = train(config, seed, report_points=task.report_points, quick_eval=False, progress=progress,
                       init_net=_init_net(task))  # fmt: skip
        attrs[keys.FRAMES_SIMULATED] += result.frames
        if result.diverged:
            attrs[keys.DIVERGED] = True
            return finish(PRUNED, None, f"diverged at {where}: {result.diverged_reason}")
        convnet = result.convnet()
        te = time.perf_counter()

        def eval_progress(done: int, total: int, where: str = where) -> None:
            limits.check(f"{where}: official evaluation at {done:,} of {total:,} frames")

        screens: list[list[float]] = []
        greedy = numpy.zeros(NUM_ACTIONS, dtype=numpy.int64)
        ev = None  # the official evaluation; None: the rung cannot count, and is not scored
        static: str | None = None  # why the chosen screen shows a static policy
        learns = result.weight_change >= task.min_weight_change
        if not learns:  # its score would be its initial weights' luck, not learning: no evaluation is spent on it
            net_json = dumps_net(convnet)
        elif task.epsilon_test_grid:  # ε_test acts only at test time: choose it for this net, train nothing again
            screened = screen_epsilons(convnet, config, task.epsilon_test_grid, task.epsilon_test_screen_runs,
                                       protocol=protocol, progress=eval_progress)  # fmt: skip
            screens = [[e, float(s.median_site), float(s.mean), int(s.runs)]
                       for e, s in zip(screened.grid, screened.screens, strict=True)]  # fmt: skip
            attrs[keys.FRAMES_SIMULATED] += screened.frames
            net_json = screened.net_json
            chosen = screened.best  # choose_epsilon's rule, applied where the halving already ranked the screens
            greedy[:] = screened.greedy[chosen]  # the official evaluation's first runs, at its ε_test
            why = _is_static(greedy) if task.prune_static else None
            if why is not None:  # static already, whatever the other runs do: the official score is not worth its time
                static = (f"static policy at rung {r} ({budget:,} iterations): {why} of the first {screened.runs} "
                          f"official runs at its ε_test {screened.grid[chosen]:g} (not scored officially)")  # fmt: skip
            else:
                config = config.replace(epsilon_test_time=screened.grid[chosen])
                top = top.replace(epsilon_test_time=screened.grid[chosen])  # the trial's config: its last rung's
                attrs.update({keys.CONFIG: top.to_mapping(), keys.SETTINGS: top.to_deepqlearn()})
                frames = screened.frames
                ev = screened.finish(chosen, progress=eval_progress, greedy_actions=greedy)  # the screen's runs kept
                attrs[keys.FRAMES_SIMULATED] += screened.frames - frames
        else:
            ev = evaluate_official(convnet, config, protocol=protocol, progress=eval_progress, greedy_actions=greedy)
            attrs[keys.FRAMES_SIMULATED] += ev.runs * ev.frames
            net_json = dumps_net(convnet)
        score = None if ev is None else float(ev.median_site)
        if score is not None and not math.isfinite(score):  # pragma: no cover - scores are finite speeds
            return finish(FAILED, None, f"official score is not finite at {where}: {score!r}")
        rung_nets[budget] = net_json
        rungs.append({
            keys.BUDGET: int(budget), keys.SEED: seed, keys.SCORE: score, keys.SECONDS: time.perf_counter() - t_rung,
            keys.TRAIN_SECONDS: result.train_seconds, keys.EVAL_SECONDS: time.perf_counter() - te,
            **({keys.OFFICIAL_MEAN: ev.mean, keys.OFFICIAL_STD: ev.std} if ev is not None else {}),
            keys.FRAMES: int(result.frames), keys.GREEDY_CHOICES: [int(n) for n in greedy],
            keys.WEIGHT_CHANGE: result.weight_change,
            **({keys.EPSILON_TEST: config.epsilon_test_time} if screens and ev is not None else {}),
            **({keys.EPSILON_SCREEN: screens} if screens else {}),
        })  # fmt: skip
        attrs[keys.CURVE] = [
            {keys.STEP: k, keys.FRAMES: int(p.frames), keys.QUICK_SCORE: None, keys.MEAN_REWARD: _finite(p.mean_reward),
             keys.LOSS: _finite(p.loss)} for k, p in enumerate(result.curve)
        ]  # fmt: skip
        if not learns:
            attrs[keys.DOES_NOT_LEARN] = True
            return finish(PRUNED, None, (
                f"does not learn at rung {r} ({budget:,} iterations): training moved its weights "
                f"{result.weight_change:.3%} from their initialisation, under [ladder] min_weight_change = "
                f"{task.min_weight_change:.2%} (not scored)"
            ))  # fmt: skip
        if static is not None:  # the chosen screen's greedy choices were one action
            attrs[keys.STATIC_POLICY] = True
            return finish(PRUNED, None, static)
        assert ev is not None and score is not None
        value = score
        step = budget // task.rungs[0]
        if report(step, attrs[keys.FRAMES_SIMULATED], score) and r < len(task.rungs) - 1:
            return finish(PRUNED, None, f"pruned after rung {r} ({budget:,} iterations, {score:.2f} mph) by the pruner")
        why = static_policy(rungs) if task.prune_static else None
        if why is not None:
            attrs[keys.STATIC_POLICY] = True
            return finish(PRUNED, None, f"static policy at rung {r} ({budget:,} iterations, {score:.2f} mph): {why}")
        if r == len(task.rungs) - 1:
            net_js = export_netjs(convnet, config.settings)
            attrs.update({keys.OFFICIAL_MEAN: ev.mean, keys.OFFICIAL_STD: ev.std,
                          keys.TRAIN_SECONDS: result.train_seconds,
                          keys.EVAL_SECONDS: rungs[-1][keys.EVAL_SECONDS]})  # fmt: skip
    assert value is not None
    return finish(COMPLETE, value, None, net_json=net_json, net_js=net_js)


def _run_soup(
    task: TrialTask, attrs: dict[str, Any], limits: _Limits, finish: Callable[..., TrialOutcome]
) -> TrialOutcome:
    """Score a weight soup (``task.init_net``, ``evaluate_only``) officially at its config's ε_test; no training."""
    from autotune import TrainConfig, dumps_net, evaluate_official, export_netjs, official_protocol

    config = TrainConfig.from_mapping(task.config)
    protocol = task.final_protocol or official_protocol(config)
    convnet = _init_net(task)
    if convnet is None:
        raise ValueError("a weight soup needs its net (TrialTask.init_net)")
    attrs.update({
        keys.CONFIG: config.to_mapping(), keys.SETTINGS: config.to_deepqlearn(), keys.INPUT_SIZE: config.net_inputs,
        keys.NUM_STATES: config.num_states, keys.PARAM_COUNT: config.param_count, keys.OFFICIAL_PROTOCOL: protocol,
        keys.FRAMES_SIMULATED: 0,
    })  # fmt: skip
    te = time.perf_counter()

    def eval_progress(done: int, total: int) -> None:
        limits.check(f"weight soup: official evaluation at {done:,} of {total:,} frames")

    ev = evaluate_official(convnet, config, protocol=protocol, progress=eval_progress)
    score = float(ev.median_site)
    if not math.isfinite(score):  # pragma: no cover - scores are finite speeds
        return finish(FAILED, None, f"official score is not finite: {score!r}")
    attrs.update({keys.FRAMES_SIMULATED: ev.runs * ev.frames, keys.OFFICIAL_MEAN: ev.mean, keys.OFFICIAL_STD: ev.std,
                  keys.TRAIN_SECONDS: 0.0, keys.EVAL_SECONDS: time.perf_counter() - te})  # fmt: skip
    return finish(COMPLETE, score, None, net_json=dumps_net(convnet), net_js=export_netjs(convnet, config.settings))


def _init_net(task: TrialTask) -> Any:
    """The net ``task`` trains on from (``TrialTask.init_net``), or None."""
    if task.init_net is None:
        return None
    from autotune import loads_net

    return loads_net(task.init_net, where=f"trial {task.number}: init_net")


def choose_epsilon(screens: Sequence[Sequence[float]]) -> int:
    """The index of the best of a net's recorded ε_test screens (``[ε, site median, mean, runs]`` each; records
    from before the halving have no runs) among those screened on the most runs: the site's statistic, then the
    mean, then the smaller ε (``autotune.learner.official.screen_order``) — the choice ``EpsilonScreens.best``
    made when the rung was scored, read back from its record.

    A screen is the official protocol's first runs at that ε_test (the same traffic and draws as the whole
    evaluation's first runs; ``autotune.screen_epsilons``): every grid value on the first stage of
    ``epsilon_test_screen_runs``, the better half on to the next, and the chosen screen is carried on into the
    official evaluation. Why per net: ε_test acts only at test time, so one training serves every value; searched
    as a training setting it took a draw's luck to pair a net that learned with a small ε_test (measured: 93–99 %
    of a cold study's draws sat at 0.4 or more, while every net that scored 74.5 drove with ε_test below 0.08)."""
    from autotune.learner.official import screen_order

    def runs(s: Sequence[float]) -> float:
        return float(s[3]) if len(s) > 3 else 0.0

    most = max(runs(s) for s in screens)
    finalists = [i for i, s in enumerate(screens) if runs(s) == most]
    return max(finalists, key=lambda i: screen_order(screens[i][0], screens[i][1], screens[i][2]))


STATIC_SHARE = 0.99
"""A net whose most frequent greedy action makes at least this share of its greedy choices is static.

Measured on the benchmark studies' nets (v2-official): every net that scored 73.5 or more chose accelerate in
42–77 % of its greedy decisions and changed lanes in most of the rest; the leaders of cold studies on the full
space chose accelerate in 99.4–100 % and scored 72.0–73.3 — "always accelerate", mixed with ε_test's random
moves, is an attractor of the space that no further training leaves (the 100 % one scored 73.21 on three
fresh seeds, to the digit)."""


def static_policy(rungs: Sequence[Mapping[str, Any]]) -> str | None:
    """Why the last rung's policy is static, or None: its greedy choices are one action (``STATIC_SHARE``), or
    its official evaluation equals the rung before's exactly (median and mean).

    Two trainings of different length that learn anything drive differently somewhere in the evaluation's
    500 × 2,000 frames, and every difference moves the run scores; an exact tie means a saturated or
    constant net mixed with ε_test's random moves, whose score is a property of its seed (measured: one scored
    73.84 at every rung on 3 race seeds, and 64.38, 73.84 and 64.05 on fresh ones).
    """
    last = rungs[-1]
    why = _is_static(last.get(keys.GREEDY_CHOICES) or [])
    if why is not None:
        return f"{why} (the policy ignores its input)"
    if len(rungs) > 1:
        prev = rungs[-2]
        if last[keys.SCORE] == prev[keys.SCORE] and last[keys.OFFICIAL_MEAN] == prev[keys.OFFICIAL_MEAN]:
            return (f"the same official score as at {prev[keys.BUDGET]:,} iterations, to the digit "
                    f"(mean {last[keys.OFFICIAL_MEAN]:.4f}): training changed nothing the car does")  # fmt: skip
    return None


def _is_static(greedy: Sequence[int] | Any) -> str | None:
    """Why greedy choice counts (one per action) are a static policy's — one action makes ``STATIC_SHARE`` of
    them — or None (None too when there were none)."""
    from sim.policies import ACTION_NAMES

    counts = [int(n) for n in greedy]
    total = sum(counts)
    if not total or max(counts) < STATIC_SHARE * total:
        return None
    top = max(counts)
    return f"the net chose {ACTION_NAMES[counts.index(top)]} in {top / total:.2%} of its {total:,} greedy decisions"


def _run(
    task: TrialTask,
    report: Report,
    attrs: dict[str, Any],
    t0: float,
    finish: Callable[..., TrialOutcome],
) -> TrialOutcome:
    from autotune import TrainConfig, dumps_net, evaluate_official, export_netjs, official_protocol
    from autotune.learner import train  # (``autotune.train`` is the ``python -m autotune.train`` module)

    config = TrainConfig.from_mapping(task.config)
    protocol = task.final_protocol or official_protocol(config)
    attrs.update({
        keys.CONFIG: config.to_mapping(),
        keys.SETTINGS: config.to_deepqlearn(),
        keys.INPUT_SIZE: config.net_inputs,
        keys.NUM_STATES: config.num_states,
        keys.PARAM_COUNT: config.param_count,
        keys.OFFICIAL_PROTOCOL: protocol,
    })  # fmt: skip
    limits = _Limits.of(task, t0)
    curve: list[dict[str, Any]] = []
    attrs[keys.CURVE] = curve
    pruned_at: list[int] = []

    def reporter(k: int, frames: int, quick_score: float) -> bool:
        curve.append({keys.STEP: k, keys.FRAMES: int(frames), keys.QUICK_SCORE: _finite(quick_score)})
        limits.check(f"at report {k}, {frames:,} frames")
        if report(k, int(frames), float(quick_score)):
            pruned_at.append(k)
            return True
        return False

    def progress(done: int, total: int) -> None:
        limits.check(f"training at {done:,} of {total:,} frames")

    try:
        result = train(
            config, task.seed, reporter, report_points=task.report_points, quick_eval_runs=task.quick_runs,
            quick_eval_frames=task.quick_frames, progress=progress, init_net=_init_net(task),
        )  # fmt: skip
    finally:
        quick_frames = len(curve) * task.quick_runs * task.quick_frames
        attrs[keys.FRAMES_SIMULATED] = quick_frames  # + training frames below (kept right on a timeout too)
    attrs[keys.FRAMES_SIMULATED] = result.frames + quick_frames
    attrs[keys.TRAIN_SECONDS] = result.train_seconds
    attrs[keys.QUICK_EVAL_SECONDS] = result.wall_seconds - result.train_seconds
    if result.diverged:
        attrs[keys.DIVERGED] = True
        return finish(PRUNED, None, f"diverged: {result.diverged_reason}")
    if pruned_at:
        return finish(PRUNED, None, f"pruned at step {pruned_at[0]} by the pruner")
    if result.stopped:  # pragma: no cover - only the reporter stops training, and it always records why
        return finish(PRUNED, None, f"stopped: {result.stop_reason}")
    limits.check("before the official evaluation")

    def eval_progress(done: int, total: int) -> None:
        limits.check(f"official evaluation at {done:,} of {total:,} frames")

    te = time.perf_counter()
    convnet = result.convnet()
    ev = evaluate_official(convnet, config, protocol=protocol, progress=eval_progress)
    net_json = dumps_net(convnet)
    net_js = export_netjs(convnet, config.settings)
    attrs[keys.EVAL_SECONDS] = time.perf_counter() - te
    attrs[keys.FRAMES_SIMULATED] += ev.runs * ev.frames
    attrs.update({keys.OFFICIAL_MEAN: ev.mean, keys.OFFICIAL_STD: ev.std})
    value = ev.median_site
    if not math.isfinite(value):  # pragma: no cover - scores are finite speeds
        return finish(FAILED, None, f"official score is not finite: {value!r}")
    return finish(COMPLETE, float(value), None, net_json=net_json, net_js=net_js)
