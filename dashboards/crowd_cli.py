"""``autotune crowd import | replay`` and ``autotune compare``: the crowd beside the automated search.

    autotune crowd import [--storage URL] [--study crowd] [--own-nets]
    autotune crowd replay [--filter EXPR] [--limit N] [--seeds K] [--workers N] [--storage URL] [--study crowd-replay]
    autotune compare STUDY [--crowd STUDY] [--replay STUDY] [--storage URL] --out report.html [--no-dashboard]

``import`` writes the packaged crowd (``dashboards.crowd_data``) as an Optuna study, one COMPLETE
trial per scored submission (idempotent); ``--own-nets`` first scores the 25 human nets with their
own weights in their own engine and official protocol (exact evaluator) and stores the scores.
``replay`` enqueues the selected crowd settings, K seeds each, as trials of the replay study
(params under the search's names, the submission's full config in ``crowd_config``); the search
driver runs them. ``--filter`` is a small expression over the CSV columns, e.g.
``engine_version == 'v2' and reported_score_mph > 70`` (parsed with ``ast``, never ``eval``).
``compare`` writes the self-contained HTML report and attaches its figures to the study in
optuna-dashboard. Bad input: one line on stderr, exit status 2.
"""

from __future__ import annotations

import argparse
import ast
import operator
import sys
from collections.abc import Callable
from typing import Any

from sim.config import ConfigError

EXIT_USAGE = 2

__all__ = ["FilterError", "compile_filter", "add_parser", "run", "score_own_nets", "enqueue_replay"]


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
    import dataclasses

    return {**{f.name: getattr(sub, f.name) for f in dataclasses.fields(sub)}, **sub.row()}


def score_own_nets(progress: Callable[[str], None] | None = None) -> dict[str, dict[str, Any]]:
    """The 25 human nets scored with their own weights, engine and official protocol (exact evaluator)."""
    from autotune.learner.brain_policy import evaluate_net
    from autotune.learner.official import OFFICIAL_PROTOCOL
    from dashboards import crowd_data

    out: dict[str, dict[str, Any]] = {}
    for nid in crowd_data.net_ids():
        net, settings = crowd_data.load_net(nid)
        protocol = OFFICIAL_PROTOCOL[settings.engine]
        result = evaluate_net(net, settings, protocol)
        out[nid] = {
            "score": result.median_site,
            "protocol": protocol,
            "mean": result.mean,
            "std": result.std,
            "runs": result.runs,
            "other_agents": result.other_agents,
            "seed": result.seed,
        }
        if progress is not None:
            progress(f"{nid}: {result.median_site:.2f} mph ({protocol}, {result.wall_seconds:.1f} s)")
    return out


def enqueue_replay(study: Any, subs: list[Any], seeds: int) -> tuple[int, int, dict[str, str]]:
    """Enqueue ``seeds`` trials per submission (skipping pairs already in the study); (added, present, skipped)."""
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
        params = crowd.encode_params(config)
        for k in range(seeds):
            if (sub.id, k) in present:
                existing += 1
                continue
            attrs = {
                "source": "crowd-replay",
                "crowd_id": sub.id,
                "seed_index": k,
                "reported_score_mph": sub.reported_score_mph,
                "crowd_config": config.to_mapping(),
            }
            study.enqueue_trial(params, user_attrs=attrs, skip_if_exists=False)
            added += 1
    return added, existing, skipped


def add_parser(subparsers: Any) -> None:
    """``autotune crowd`` (import, replay) and ``autotune compare``: options, help and ``func=run``."""
    p = subparsers.add_parser(
        "crowd",
        help="the human crowd's submissions as an Optuna study (import) or re-run by our learner (replay)",
        description="import: write the 164-submission crowd sample as an Optuna study; replay: enqueue crowd "
        "settings as trials of a study that the search driver trains and scores with the exact engine.",
    )
    actions = p.add_subparsers(dest="crowd_action", metavar="<action>", required=True)
    imp = actions.add_parser("import", help="write the crowd as an Optuna study (one trial per scored submission)")
    imp.add_argument("--storage", default="", help="journal file or SQLAlchemy URL (default: runs/<study>/journal.log)")
    imp.add_argument("--study", default="crowd", help="study name (default: crowd)")
    imp.add_argument(
        "--own-nets", action="store_true", help="also score the 25 human nets with their own weights (exact engine)"
    )
    imp.set_defaults(func=run, command_name="crowd-import")
    rep = actions.add_parser("replay", help="enqueue crowd settings (K seeds each) as trials of a replay study")
    rep.add_argument("--filter", default="", help="expression over CSV columns, e.g. \"engine_version == 'v2'\"")
    rep.add_argument("--limit", type=int, default=0, help="replay at most N submissions (0: all selected)")
    rep.add_argument("--seeds", type=int, default=1, help="training seeds per setting (default 1)")
    rep.add_argument("--workers", type=int, default=1, help="parallel trials when the driver runs them")
    rep.add_argument("--storage", default="", help="journal file or SQLAlchemy URL (default: runs/<study>/journal.log)")
    rep.add_argument("--study", default="crowd-replay", help="study name (default: crowd-replay)")
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
    cmp.add_argument("--storage", default="", help="journal file or SQLAlchemy URL (default: runs/<study>/journal.log)")
    cmp.add_argument("--out", required=True, help="HTML file to write")
    cmp.add_argument("--seed", type=int, default=0, help="seed of the t-SNE and importance evaluators (default 0)")
    cmp.add_argument("--no-dashboard", action="store_true", help="do not attach the figures to the study")
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
    from dashboards import crowd_data

    if args.seeds < 1 or args.limit < 0 or args.workers < 1:
        raise ConfigError("--seeds and --workers must be ≥ 1 and --limit ≥ 0")
    subs = list(crowd_data.load_submissions())
    if args.filter:
        keep = compile_filter(args.filter, list(_row_namespace(subs[0])))
        subs = [s for s in subs if keep(_row_namespace(s))]
    if args.limit:
        subs = subs[: args.limit]
    storages = open_storage(args.storage, args.study)
    study = optuna.create_study(
        study_name=args.study, storage=storages.storage, direction="maximize", load_if_exists=True
    )
    study.set_user_attr("source", "crowd-replay")
    added, existing, skipped = enqueue_replay(study, subs, args.seeds)
    print(
        f"{storages.url}: study '{args.study}': {len(subs)} crowd setting(s) selected; {added} trial(s) enqueued, "
        f"{existing} already there; {len(skipped)} skipped"
    )
    for sid, reason in skipped.items():
        print(f"  skipped {reason}" if reason.startswith(sid) else f"  skipped {sid}: {reason}")
    study.set_user_attr("replay_workers", args.workers)
    # TODO(issue 8 driver): run the enqueued trials here once autotune/search/driver.py exposes its entry point
    print("the enqueued trials wait in the study; the search driver runs them")
    return 0


def _compare(args: argparse.Namespace) -> int:
    from autotune.search.storage import load_study, open_storage, study_names
    from dashboards import crowd, report

    storages = open_storage(args.storage, args.study, heartbeat=False)
    automated = load_study(storages, args.study)
    if args.crowd:
        crowd_storages = open_storage(args.storage, args.crowd, heartbeat=False)
        crowd_study = load_study(crowd_storages, args.crowd)
    else:
        crowd_storages = open_storage(args.storage, crowd.CROWD_STUDY, heartbeat=False)
        has = crowd.CROWD_STUDY in study_names(crowd_storages)
        crowd_study = crowd.crowd_study(crowd_storages.storage if has else None)
    replay = None
    replay_name = args.replay or crowd.REPLAY_STUDY
    replay_storages = open_storage(args.storage, replay_name, heartbeat=False)
    if args.replay or replay_name in study_names(replay_storages):
        replay = load_study(replay_storages, replay_name)
    built = report.build_report(automated, crowd_study, replay=replay, seed=args.seed)
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
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_USAGE
