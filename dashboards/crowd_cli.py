"""``autotune crowd import | replay`` and ``autotune compare``: the crowd beside the automated search.

    autotune crowd import [--storage URL] [--study crowd] [--own-nets]
    autotune crowd replay [--filter EXPR] [--limit N] [--seeds K] [--workers N] [--storage URL] [--study crowd-replay]
                          [--enqueue-only]
    autotune compare STUDY [--crowd STUDY] [--replay STUDY] [--storage URL] --out report.html [--no-dashboard]
                     [--spread-runs N | --no-spread]

``import`` writes the packaged crowd (``dashboards.crowd_data``) as an Optuna study, one COMPLETE
trial per scored submission (idempotent), with the shipped own-weight scores of the 25 human nets
(``dashboards.measured``); ``--own-nets`` scores them again first (exact evaluator, own engine and
official protocol: the same numbers) and stores those.
``replay`` enqueues the selected crowd settings, K seeds each, as trials of the replay study
(params under the search's names, the submission's full config in the ``config`` user attr, a seed
fixed by (crowd id, seed index)) and runs them with the search driver on ``--workers`` Ray
workers: the whole training (the submission's own trainIterations, never fewer) and the official
protocol of the submission's engine, no pruning. Then it prints self-reported against replayed
(mean over seeds). Rerunning enqueues only missing (setting, seed) pairs and runs only waiting
trials. ``--filter`` is a small expression over the CSV columns, e.g.
``engine_version == 'v2' and reported_score_mph > 70`` (parsed with ``ast``, never ``eval``).
``compare`` writes the self-contained HTML report and attaches its figures to the study in
optuna-dashboard; its measured-crowd panels read the package data (``dashboards.measured``,
``dashboards.spread``: own-weight scores, the replay table, the site's number under 50 protocol
seeds, up to ``--spread-runs`` runs per evaluation), so it scores nothing itself. Bad input: one
line on stderr, exit status 2.
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import operator
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from typing import TYPE_CHECKING, Any

from autotune.cliutil import add_storage_arguments, fail
from sim.config import ConfigError

if TYPE_CHECKING:
    from autotune.search.spec import StudySpec


__all__ = [
    "FilterError", "compile_filter", "add_parser", "run", "score_own_nets", "enqueue_replay", "replay_seed",
    "replay_spec", "replay_table",
]  # fmt: skip

REPLAY_TRIAL_TIMEOUT_S = 24 * 3600.0  # a crowd setting trains as long as it says (up to 1,000,000 iterations)


class FilterError(ConfigError):
    """A --filter expression that is not allowed or names an unknown column."""


_COMPARE: dict[type, Callable[[Any, Any], bool]] = {
    ast.Eq: operator.eq,
    ast.NotEq: operator.ne,
    ast.Lt: operator.lt,
    ast.LtE: operator.le,
    ast.Gt: operator.gt,
    ast.GtE: operator.ge,
    ast.In: lambda a, b: a in b,
    ast.NotIn: lambda a, b: a not in b,
    ast.Is: operator.is_,
    ast.IsNot: operator.is_not,
}
_ARITH: dict[type, Callable[[Any, Any], Any]] = {
    ast.Add: operator.add,
    ast.Sub: operator.sub,
    ast.Mult: operator.mul,
    ast.Div: operator.truediv,
}


def compile_filter(expr: str, columns: list[str]) -> Callable[[dict[str, Any]], bool]:
    """A predicate over a row mapping (column → value) from a restricted expression.

    Allowed: column names, numbers, strings, True/False/None, lists/tuples of those, ``and or not``,
    comparisons (``== != < <= > >= in not in is is not``) and ``+ - * /``. A comparison with a blank
    (None) cell is False, except ``==``/``!=``/``is``.
    """
    try:
        tree = ast.parse(expr, mode="eval")
    except SyntaxError as exc:
        raise FilterError(f"--filter: not an expression ({exc.msg} at column {exc.offset}): {expr!r}") from None

    def check(node: ast.AST) -> None:
        if isinstance(node, ast.Name):
            if node.id not in columns and node.id not in ("True", "False", "None"):
                import difflib

                near = difflib.get_close_matches(node.id, columns, n=1)
                hint = f"; did you mean '{near[0]}'?" if near else ""
                raise FilterError(f"--filter: unknown column '{node.id}'{hint}")
            return
        allowed = (
            ast.Expression,
            ast.BoolOp,
            ast.And,
            ast.Or,
            ast.UnaryOp,
            ast.Not,
            ast.USub,
            ast.Compare,
            ast.Constant,
            ast.List,
            ast.Tuple,
            ast.Load,
            ast.BinOp,
            *_COMPARE,
            *_ARITH,
        )
        if not isinstance(node, allowed):
            raise FilterError(f"--filter: {type(node).__name__} is not allowed in a filter: {expr!r}")
        for child in ast.iter_child_nodes(node):
            check(child)

    check(tree)

    def value(node: ast.AST, row: dict[str, Any]) -> Any:
        if isinstance(node, ast.Expression):
            return value(node.body, row)
        if isinstance(node, ast.Constant):
            return node.value
        if isinstance(node, ast.Name):
            return row[node.id]
        if isinstance(node, (ast.List, ast.Tuple)):
            return [value(e, row) for e in node.elts]
        if isinstance(node, ast.BoolOp):
            parts = (bool(value(v, row)) for v in node.values)
            return all(parts) if isinstance(node.op, ast.And) else any(parts)
        if isinstance(node, ast.UnaryOp):
            inner = value(node.operand, row)
            if isinstance(node.op, ast.Not):
                return not inner
            return None if inner is None else -inner
        if isinstance(node, ast.BinOp):
            left, right = value(node.left, row), value(node.right, row)
            if left is None or right is None:
                return None
            return _ARITH[type(node.op)](left, right)
        assert isinstance(node, ast.Compare)
        left = value(node.left, row)
        for op, comparator in zip(node.ops, node.comparators, strict=True):
            right = value(comparator, row)
            if (left is None or right is None) and not isinstance(op, (ast.Eq, ast.NotEq, ast.Is, ast.IsNot)):
                return False
            try:
                if not _COMPARE[type(op)](left, right):
                    return False
            except TypeError:
                raise FilterError(f"--filter: cannot compare {left!r} with {right!r} in {expr!r}") from None
            left = right
        return True

    return lambda row: bool(value(tree, row))


def _row_namespace(sub: Any) -> dict[str, Any]:
    """A submission under its CSV column names and its record field names."""
    return dict(sub.namespace())


def score_own_nets(progress: Callable[[str], None] | None = None) -> dict[str, dict[str, Any]]:
    """The 25 human nets scored with their own weights, engine and official protocol (exact evaluator)."""
    from dashboards import crowd, measured

    def show(s: measured.OwnNetScore) -> None:
        if progress is not None:
            progress(f"{s.crowd_id}: {s.score:.2f} mph ({s.protocol}, {s.seconds:.1f} s)")

    return crowd.own_net_attrs(measured.score_own_nets(progress=show))


def replay_seed(crowd_id: str, seed_index: int) -> int:
    """The training seed of seed index k of a crowd setting (``crowd_replay.replay_seed``, imported when used)."""
    from dashboards import crowd_replay

    return crowd_replay.replay_seed(crowd_id, seed_index)


def enqueue_replay(study: Any, subs: list[Any], seeds: int) -> tuple[int, int, dict[str, str]]:
    """Enqueue ``seeds`` trials per submission (skipping pairs already in the study); (added, present, skipped)."""
    from autotune.search.driver import CONFIG_ATTR
    from dashboards import crowd, crowd_data

    present = {
        (t.user_attrs.get("crowd_id"), t.user_attrs.get("seed_index"))
        for t in study.get_trials(deepcopy=False)
        if t.user_attrs.get("crowd_id") is not None
    }
    added = existing = 0
    skipped: dict[str, str] = {}
    for sub in subs:
        try:
            config = crowd_data.train_config(sub)
        except crowd_data.CrowdDataError as exc:
            skipped[sub.id] = str(exc)
            continue
        params = crowd.crowd_params(config)
        for k in range(seeds):
            if (sub.id, k) in present:
                existing += 1
                continue
            attrs = {
                "source": "crowd-replay",
                "crowd_id": sub.id,
                "seed_index": k,
                "reported_score_mph": sub.reported_score_mph,
                "engine_version": sub.engine_version,
                CONFIG_ATTR: config.to_mapping(),  # the driver trains this (settings params cannot carry included)
                "seed": replay_seed(sub.id, k),
            }
            study.enqueue_trial(params, user_attrs=attrs, skip_if_exists=False)
            added += 1
    return added, existing, skipped


def replay_spec(
    name: str, *, storage: str, workers: int, n_trials: int, params: Iterable[dict[str, Any]] = ()
) -> StudySpec:
    """The replay study's spec: the paper's space (``space.DEFAULT_SPACE``, = paper.toml), no pruner, a long limit.

    Random sampler (only a v1 trial's unused ``other_agents`` is ever drawn), no pruning (a replay
    trains to the end), ``report_points`` 5 for the learning curve. The space is widened to hold
    every enqueued value in ``params`` (the crowd went beyond the paper's bounds: 50 lanes, 1-neuron
    layers, linear and svm outputs), so Optuna stores them without complaint; activation choices
    are the same in every replay (a categorical's choices may not change within a study).
    """
    import dataclasses

    from autotune.search.space import DEFAULT_SPACE
    from autotune.search.spec import parse_spec
    from dashboards.crowd import ACTIVATION_CHOICES

    spec = parse_spec(
        {
            "study": {
                "name": name, "sampler": "random", "pruner": "none", "n_trials": n_trials, "seed": 0,
                "storage": storage, "trial_timeout_s": REPLAY_TRIAL_TIMEOUT_S,
            },
            "space": DEFAULT_SPACE,
            "evaluation": {"report_points": 5, "quick_runs": 10, "quick_frames": 2000, "n_warmup_steps": 0},
            "resources": {"workers": workers},
        },
        source="crowd replay",
    )  # fmt: skip
    seen: dict[str, list[Any]] = {}
    for p in params:
        for key, value in p.items():
            seen.setdefault(key.rsplit("_", 1)[0] if key.startswith(("neurons_", "activation_")) else key, []).append(
                value
            )
    dims = []
    for d in spec.space:
        if d.kind == "categorical":
            d = dataclasses.replace(d, choices=(*d.choices, *(c for c in ACTIVATION_CHOICES if c not in d.choices)))
        elif seen.get(d.name):
            assert d.low is not None and d.high is not None
            low, high = min(d.low, *seen[d.name]), max(d.high, *seen[d.name])
            if d.log and low <= 0:  # cannot widen a log scale to 0: Optuna stores the value with a warning
                low = d.low
            d = dataclasses.replace(d, low=low, high=high)
        dims.append(d)
    return dataclasses.replace(spec, space=tuple(dims))


@dataclasses.dataclass(frozen=True)
class ReplayRow:
    """One replayed crowd setting: its self-reported score beside our seeds' official scores."""

    crowd_id: str
    engine: str
    """Engine of the submission ('v1' or 'v2'); its official protocol scored the replay."""
    reported: float | None
    """Self-reported score [mph] (None: the submission reported none)."""
    scores: tuple[float, ...]
    """Official score of each complete seed [mph]."""
    unfinished: int
    """Seeds of this setting not complete (waiting, running, failed or pruned)."""

    @property
    def mean(self) -> float | None:
        """Mean over the complete seeds [mph]."""
        return sum(self.scores) / len(self.scores) if self.scores else None


def replay_table(study: Any, subs: Sequence[Any]) -> list[ReplayRow]:
    """Per submission of ``subs`` (in that order): the complete replay scores in ``study``."""
    from optuna.trial import TrialState

    rows = []
    trials = study.get_trials(deepcopy=False)
    for sub in subs:
        mine = [t for t in trials if t.user_attrs.get("crowd_id") == sub.id]
        if not mine:
            continue
        latest = {}  # seed index -> its last attempt (a retry supersedes the failure it retries)
        for t in mine:
            latest[t.user_attrs.get("seed_index")] = t
        done = tuple(float(t.value) for t in latest.values() if t.state == TrialState.COMPLETE)
        rows.append(ReplayRow(sub.id, sub.engine_version, sub.reported_score_mph, done, len(latest) - len(done)))
    return rows


def format_replay_table(rows: Sequence[ReplayRow]) -> str:
    """The rows as an aligned text table (crowd id, engine, self-reported, replayed mean ± sd over seeds)."""

    def num(x: float | None) -> str:
        return "—" if x is None else f"{x:.2f}"

    head = ("crowd id", "engine", "self-reported", "replayed mean", "sd", "seeds")
    body = []
    for r in rows:
        sd = None
        if len(r.scores) > 1:
            m = r.mean or 0.0
            sd = (sum((x - m) ** 2 for x in r.scores) / (len(r.scores) - 1)) ** 0.5
        seeds = f"{len(r.scores)}" + (f" (+{r.unfinished} not complete)" if r.unfinished else "")
        body.append((r.crowd_id, r.engine, num(r.reported), num(r.mean), num(sd), seeds))
    widths = [max(len(row[i]) for row in (head, *body)) for i in range(len(head))]
    return "\n".join("  ".join(c.ljust(w) for c, w in zip(row, widths, strict=True)).rstrip() for row in (head, *body))


def add_parser(subparsers: Any) -> None:
    """``autotune crowd`` (import, replay) and ``autotune compare``: options, help and ``func=run``."""
    p = subparsers.add_parser(
        "crowd",
        help="the human crowd's submissions as an Optuna study (import) or re-run by our learner (replay)",
        description="import: write the crowd sample's 116 scored submissions (of 164) as an Optuna study whose values "
        "are the authors' claims; replay: enqueue crowd "
        "settings as trials of a study that the search driver trains and scores with the exact engine.",
    )
    actions = p.add_subparsers(dest="crowd_action", metavar="<action>", required=True)
    imp = actions.add_parser("import", help="write the crowd as an Optuna study (one trial per scored submission)")
    add_storage_arguments(imp, artifacts_help=None)
    imp.add_argument("--study", default="crowd", help="study name (default: crowd)")
    imp.add_argument(
        "--own-nets",
        action="store_true",
        help="score the 25 human nets with their own weights now (exact engine; default: the shipped scores)",
    )
    imp.set_defaults(func=run, command_name="crowd-import")
    rep = actions.add_parser(
        "replay", help="retrain and score crowd settings (K seeds each) with our learner and the exact engine"
    )
    rep.add_argument("--filter", default="", help="expression over CSV columns, e.g. \"engine_version == 'v2'\"")
    rep.add_argument("--limit", type=int, default=0, help="replay at most N submissions (0: all selected)")
    rep.add_argument("--seeds", type=int, default=1, help="training seeds per setting (default 1)")
    rep.add_argument("--workers", type=int, default=1, help="Ray workers = trials trained in parallel (default 1)")
    add_storage_arguments(rep, artifacts_help=None)
    rep.add_argument("--study", default="crowd-replay", help="study name (default: crowd-replay)")
    rep.add_argument(
        "--enqueue-only", action="store_true", help="only enqueue; a later replay of the same study runs them"
    )
    rep.set_defaults(func=run, command_name="crowd-replay")

    cmp = subparsers.add_parser(
        "compare",
        help="HTML report: an automated study beside the crowd (the paper's figures and four insights)",
        description="Write one self-contained HTML report comparing STUDY with the crowd, and attach its figures "
        "and a note to STUDY for optuna-dashboard.",
    )
    cmp.add_argument("study", help="the automated study")
    cmp.add_argument("--crowd", default="", help="crowd study (default: 'crowd' in the storage, else the package data)")
    cmp.add_argument("--replay", default="", help="crowd replay study (default: 'crowd-replay' if the storage has it)")
    add_storage_arguments(cmp, artifacts_help=None)
    cmp.add_argument("--out", required=True, help="HTML file to write")
    cmp.add_argument("--seed", type=int, default=0, help="seed of the t-SNE and importance evaluators (default 0)")
    cmp.add_argument("--no-dashboard", action="store_true", help="do not attach the figures to the study")
    cmp.add_argument(
        "--spread-runs", type=int, default=500, metavar="N",
        help="spread panel: runs per evaluation shown up to N (default 500, the site's; shipped data)",
    )  # fmt: skip
    cmp.add_argument("--no-spread", action="store_true", help="leave out the evaluation-spread panel")
    cmp.set_defaults(func=run, command_name="compare")


def _import(args: argparse.Namespace) -> int:
    from autotune.search.storage import open_storage
    from dashboards.crowd import import_crowd

    storages = open_storage(args.storage, args.study)
    own = score_own_nets(lambda line: print(line, file=sys.stderr)) if args.own_nets else None
    _study, result = import_crowd(storages.storage, args.study, own_net_scores=own)
    unscored = sum(1 for r in result.skipped.values() if r == "no reported score")
    print(
        f"{storages.url}: study '{result.study_name}': {result.added} trial(s) added, {result.existing} already "
        f"there; skipped {len(result.skipped)} submission(s) ({unscored} without a reported score, "
        f"{len(result.skipped) - unscored} with settings our learner refuses)"
    )
    for sid, reason in result.skipped.items():
        if reason != "no reported score":
            print(f"  skipped {sid}: {reason}")
    if own:
        print(f"own-net scores stored for {len(own)} net(s)")
    return 0


def _replay(args: argparse.Namespace) -> int:
    import optuna

    from autotune.search.storage import open_storage
    from dashboards import crowd, crowd_data

    if args.seeds < 1 or args.limit < 0 or args.workers < 1:
        raise ConfigError("--seeds and --workers must be ≥ 1 and --limit ≥ 0")
    subs = list(crowd_data.load_submissions())
    if args.filter:
        keep = compile_filter(args.filter, list(_row_namespace(subs[0])))
        subs = [s for s in subs if keep(_row_namespace(s))]
    if args.limit:
        subs = subs[: args.limit]
    storages = open_storage(args.storage, args.study)
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    study = optuna.create_study(
        study_name=args.study, storage=storages.storage, direction="maximize", load_if_exists=True
    )
    study.set_user_attr("source", "crowd-replay")
    crowd.set_metric_name(study, crowd.REPLAY_METRIC)
    added, existing, skipped = enqueue_replay(study, subs, args.seeds)
    print(
        f"{storages.url}: study '{args.study}': {len(subs)} crowd setting(s) selected; {added} trial(s) enqueued, "
        f"{existing} already there; {len(skipped)} skipped"
    )
    for sid, reason in skipped.items():
        print(f"  skipped {reason}" if reason.startswith(sid) else f"  skipped {sid}: {reason}")
    if args.enqueue_only:
        print(f"the enqueued trials wait in the study; 'autotune crowd replay --study {args.study}' runs them")
        return 0
    from autotune import TrainConfig
    from autotune.search.driver import CONFIG_ATTR, Driver

    trials = study.get_trials(deepcopy=False)
    if not trials:
        print("nothing to run: the study has no trial")
        return 0
    waiting = sum(1 for t in trials if t.state == optuna.trial.TrialState.WAITING)
    spec = replay_spec(
        args.study, storage=args.storage, workers=args.workers,
        n_trials=sum(1 for t in trials if "retry_of" not in t.user_attrs),  # exactly the enqueued ones
        params=[crowd.crowd_params(TrainConfig.from_mapping(t.user_attrs[CONFIG_ATTR]))
                for t in trials if CONFIG_ATTR in t.user_attrs],
    )  # fmt: skip
    if waiting:
        print(f"training {waiting} trial(s) on {args.workers} worker(s): full training, official protocol")
    driver = Driver(spec, storages, progress=_ReplayProgress(waiting))
    try:
        counts = driver.run()  # starts no Ray when nothing waits (a rerun)
    except KeyboardInterrupt:
        print("interrupted: running trials failed (retryable); rerun the same command to go on", file=sys.stderr)
        return 130
    ran = counts.complete + counts.pruned + counts.failed - sum(1 for t in trials if t.state.is_finished())
    if ran:
        print(
            f"ran {ran} trial(s) in {counts.elapsed_s:.0f} s; study: {counts.complete} complete, {counts.pruned} "
            f"pruned, {counts.failed} failed ({counts.retries} retries)"
        )
    else:
        print("nothing to run: every trial of the study has run already")
    rows = replay_table(study, subs)
    if rows:
        print(format_replay_table(rows))
    return 0


class _ReplayProgress:
    """One stderr line whenever a replay trial finishes."""

    def __init__(self, total: int) -> None:
        self.total = total
        self.base: int | None = None
        self.seen = 0
        self.t0 = time.perf_counter()

    def __call__(self, c: Any) -> None:
        finished = c.complete + c.pruned + c.failed
        if self.base is None:
            self.base = finished
        done = finished - self.base
        if done != self.seen:
            self.seen = done
            print(
                f"  replay: {done} finished of {self.total} ({c.complete} complete, {c.failed} failed), "
                f"{c.running} running, {time.perf_counter() - self.t0:.0f} s",
                file=sys.stderr,
            )


def _stored_study(storage: str, name: str) -> Any:
    """The study ``name`` if ``storage`` (or its embedded journal) holds it, else None — creating nothing."""
    from autotune.search.storage import UnknownStudyError, load_study, open_storage

    try:
        return load_study(open_storage(storage, name, heartbeat=False, create=False), name)
    except UnknownStudyError:
        return None


def _compare(args: argparse.Namespace) -> int:
    from autotune.search.storage import load_study, open_storage
    from dashboards import crowd, report
    from dashboards.extract import Empty

    if not args.no_spread and args.spread_runs < 2:
        raise ConfigError(f"--spread-runs: need at least 2 runs, got {args.spread_runs}")
    from dashboards.spread import load_spread_runs

    storages = open_storage(args.storage, args.study, heartbeat=False, create=False)
    automated = load_study(storages, args.study)
    if args.crowd:
        crowd_storages = open_storage(args.storage, args.crowd, heartbeat=False, create=False)
        crowd_study = load_study(crowd_storages, args.crowd)
    else:
        stored = _stored_study(args.storage, crowd.CROWD_STUDY)
        crowd_study = stored if stored is not None else crowd.crowd_study(None)
    replay = None
    if args.replay:
        replay = load_study(open_storage(args.storage, args.replay, heartbeat=False, create=False), args.replay)
    else:
        replay = _stored_study(args.storage, crowd.REPLAY_STUDY)
    spread = Empty("not drawn (--no-spread)") if args.no_spread else load_spread_runs(args.spread_runs)
    built = report.build_report(automated, crowd_study, replay=replay, spread=spread, seed=args.seed)
    path = report.write_html(built, args.out)
    shown = sum(1 for s in built.sections if not isinstance(s.figure, report.Empty))
    print(f"wrote {path} ({shown} of {len(built.sections)} panels with data)")
    for s in built.sections:
        if isinstance(s.figure, report.Empty):
            print(f"  {s.title}: {s.figure.reason}")
    if not args.no_dashboard:
        ids = report.attach_to_dashboard(automated, built)
        print(f"attached {len(ids)} figure(s) and a note to study '{args.study}' for optuna-dashboard")
    return 0


def run(args: argparse.Namespace) -> int:
    """Run the chosen command; 0 on success, 2 after a one-line error."""
    from dashboards.crowd_data import CrowdDataError

    commands = {"crowd-import": _import, "crowd-replay": _replay, "compare": _compare}
    try:
        return commands[args.command_name](args)
    except (ConfigError, CrowdDataError) as exc:
        return fail(str(exc))
