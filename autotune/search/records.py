"""The one read API for studies: plain, frozen records of studies and trials, summaries, exports, reproductions.

Everything above ``autotune.search`` (the reports, the commands) reads studies here and gets plain
data — ``StudyRecord`` / ``TrialRecord`` (numbers, state names, values, params with their
``Distribution``, user attrs, times), artifacts' text — never an Optuna object: Optuna stays
inside ``autotune.search``. The records follow the trial contract (user attrs named in
``autotune.search.keys``: ``config``, ``settings``, ``seed``, ``curve``, ``frames_simulated``,
``official_*``, ``artifact_net_json`` / ``artifact_net_js``, …). Everything here reads a storage
opened by ``storage.open_storage``; nothing writes to it.
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import math
import tempfile
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import optuna
from optuna.artifacts import download_artifact
from optuna.distributions import BaseDistribution, CategoricalDistribution, FloatDistribution, IntDistribution
from optuna.trial import FrozenTrial, TrialState

from autotune.search import keys
from autotune.search.storage import Storages, UnknownStudyError, load_study, open_storage, study_names
from sim.config import ConfigError

if TYPE_CHECKING:
    from autotune.convnet.spec import ConvNet
    from autotune.learner.config import TrainConfig

__all__ = [
    "STATES",
    "FINISHED_STATES",
    "MIN_RATE_SPAN_S",
    "Distribution",
    "TrialRecord",
    "StudyRecord",
    "RecordError",
    "Reproduction",
    "read_study",
    "read_study_if_present",
    "find_study",
    "snapshot",
    "artifact_text",
    "best_net",
    "kept_rungs",
    "net_rank",
    "scored_nets",
    "best_trial_record",
    "export_best",
    "export_best_net",
    "export_trial",
    "format_summary",
    "rescore_trial",
    "retrain_trial",
    "soup_net",
    "stored_net",
    "race_setup",
    "race_summary",
    "study_resources",
    "study_summary",
    "trial_record",
]

STATES: tuple[str, ...] = tuple(state.name for state in TrialState)
"""Every trial state's name: RUNNING, COMPLETE, PRUNED, FAIL, WAITING."""
FINISHED_STATES: tuple[str, ...] = ("COMPLETE", "PRUNED", "FAIL")
"""The states a trial ends in."""
MIN_RATE_SPAN_S = 1.0
"""``status`` gives no rates over a shorter span: a handful of trials in milliseconds is no throughput."""
_RECORD_ATTRS = (
    keys.SOURCE, keys.SEED, keys.CONFIG, keys.SETTINGS, keys.INPUT_SIZE, keys.NUM_STATES, keys.PARAM_COUNT,
    keys.FRAMES_SIMULATED, keys.TRAIN_SECONDS, keys.EVAL_SECONDS, keys.OFFICIAL_PROTOCOL, keys.OFFICIAL_MEAN,
    keys.OFFICIAL_STD, keys.DIVERGED, keys.CAUSE, keys.WORKER, keys.RETRY_OF, keys.ARTIFACT_NET_JSON,
    keys.ARTIFACT_NET_JS,
)  # fmt: skip


class RecordError(ConfigError):
    """A trial record that is missing or incomplete (no finished trial, no such number, no artifact)."""


# --------------------------------------------------------------------------------------------
# plain records
# --------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Distribution:
    """The range a parameter was drawn from, as Optuna stored it (plain data)."""

    kind: str
    """'int', 'float' or 'categorical'."""
    low: float | None = None
    """Smallest value (inclusive); None for categorical."""
    high: float | None = None
    """Largest value (inclusive); None for categorical."""
    log: bool = False
    """Drawn uniformly in log(value)."""
    step: float | None = None
    """Grid step from low (ints: 1 unless set); None: continuous."""
    choices: tuple[Any, ...] = ()
    """The categories (categorical only)."""


@dataclasses.dataclass(frozen=True)
class TrialRecord:
    """One trial as stored: its state, value, parameters and user attrs (the trial contract, ``keys``)."""

    number: int
    """The trial's number in its study (0, 1, …)."""
    state: str
    """One of ``STATES``."""
    value: float | None
    """The objective: the official score [mph] of a COMPLETE trial; None otherwise."""
    params: Mapping[str, Any]
    """Sampled parameters, in sampling coordinates (``one_minus_gamma``, ``n_layers``, …)."""
    distributions: Mapping[str, Distribution]
    """The range each parameter was drawn from."""
    user_attrs: Mapping[str, Any]
    """The trial record (keys in ``autotune.search.keys``)."""
    datetime_start: dt.datetime | None = None
    """When the trial started (local time, as Optuna stores it)."""
    datetime_complete: dt.datetime | None = None
    """When it finished (None while it runs or waits)."""

    @property
    def duration_s(self) -> float | None:
        """Wall time from start to finish [s]."""
        if self.datetime_start is None or self.datetime_complete is None:
            return None
        return (self.datetime_complete - self.datetime_start).total_seconds()


@dataclasses.dataclass(frozen=True)
class StudyRecord:
    """A study as stored: name, direction, user attrs and every trial in number order."""

    name: str
    direction: str
    """'MAXIMIZE' (every autotune study: scores) or 'MINIMIZE'."""
    user_attrs: Mapping[str, Any]
    """Study user attrs (``keys.STUDY_SPEC``, ``keys.SOURCE``, …)."""
    trials: tuple[TrialRecord, ...]
    """Every trial, by number."""
    best_number: int | None = None
    """The best COMPLETE trial's number as Optuna ranks it; None before one completes."""

    @property
    def best(self) -> TrialRecord | None:
        """The best COMPLETE trial (None before one completes)."""
        return None if self.best_number is None else self.trials[self.best_number]

    def with_states(self, *states: str) -> list[TrialRecord]:
        """The trials in any of ``states`` (names of ``STATES``), by number."""
        return [t for t in self.trials if t.state in states]


def _distribution(d: BaseDistribution) -> Distribution:
    if isinstance(d, CategoricalDistribution):
        return Distribution("categorical", choices=tuple(d.choices))
    if isinstance(d, IntDistribution):
        return Distribution("int", d.low, d.high, d.log, d.step)
    if isinstance(d, FloatDistribution):
        return Distribution("float", d.low, d.high, d.log, d.step)
    raise TypeError(f"unsupported Optuna distribution {type(d).__name__}")  # pragma: no cover - Optuna's three


def to_optuna_distribution(d: Distribution) -> BaseDistribution:
    """The Optuna distribution a ``Distribution`` describes (for writers inside ``autotune.search``)."""
    if d.kind == "categorical":
        return CategoricalDistribution(d.choices)
    assert d.low is not None and d.high is not None
    if d.kind == "int":
        return IntDistribution(int(d.low), int(d.high), log=d.log, step=int(d.step or 1))
    return FloatDistribution(float(d.low), float(d.high), log=d.log, step=d.step)


def _trial(t: FrozenTrial) -> TrialRecord:
    return TrialRecord(
        number=t.number,
        state=t.state.name,
        value=t.value,
        params=dict(t.params),
        distributions={k: _distribution(d) for k, d in t.distributions.items()},
        user_attrs=dict(t.user_attrs),
        datetime_start=t.datetime_start,
        datetime_complete=t.datetime_complete,
    )


def snapshot(study: optuna.Study) -> StudyRecord:
    """An Optuna study as a plain ``StudyRecord`` (what ``read_study`` returns; tests pass in-memory studies)."""
    best = _best(study)
    return StudyRecord(
        name=study.study_name,
        direction=study.direction.name,
        user_attrs=dict(study.user_attrs),
        trials=tuple(_trial(t) for t in study.get_trials(deepcopy=False)),
        best_number=None if best is None else best.number,
    )


def read_study(storages: Storages, study_name: str) -> StudyRecord:
    """The stored study ``study_name`` as plain records; ``UnknownStudyError`` (nearest names) if absent."""
    return snapshot(load_study(storages, study_name))


def read_study_if_present(storages: Storages, study_name: str) -> StudyRecord | None:
    """``read_study``, or None when the storage holds no study of that name."""
    return read_study(storages, study_name) if study_name in study_names(storages) else None


def find_study(storage: str, study_name: str) -> StudyRecord | None:
    """The study ``study_name`` if ``storage`` (``--storage``; '' = its embedded journal) holds it, else None.

    Creates nothing: a storage that does not exist yet holds no study.
    """
    try:
        storages = open_storage(storage, study_name, read_only=True)
    except UnknownStudyError:  # no journal or SQLite file, an empty database: no study
        return None
    return read_study_if_present(storages, study_name)


def artifact_text(storages: Storages, trial: TrialRecord, key: str) -> str | None:
    """The text of the artifact whose id the trial stores under user attr ``key`` (None: no such attr).

    ``RecordError`` when the id is there but the artifact store does not hold it.
    """
    return _artifact_by_id(storages, trial, trial.user_attrs.get(key), key)


def net_text(storages: Storages, number: int, user_attrs: Mapping[str, Any], budget: int | None) -> str:
    """The Net JSON of trial ``number``'s net (``budget`` None: its value's, ``artifact_net_json``; else its kept
    rung's, ``artifact_rung_nets``) from the artifact store; ``RecordError`` naming the trial when not stored."""
    if budget is None:
        artifact_id, what = user_attrs.get(keys.ARTIFACT_NET_JSON), f"user attr {keys.ARTIFACT_NET_JSON}"
    else:
        artifact_id = (user_attrs.get(keys.ARTIFACT_RUNG_NETS) or {}).get(str(budget))
        what = f"user attr {keys.ARTIFACT_RUNG_NETS} for {budget}"
    text = _download(storages, number, artifact_id, what)
    if text is None:
        raise RecordError(f"trial {number}: no trained network stored ({what} missing)")
    return text


def _artifact_by_id(storages: Storages, trial: TrialRecord, artifact_id: Any, key: str) -> str | None:
    return _download(storages, trial.number, artifact_id, key)


def _download(storages: Storages, number: int, artifact_id: Any, key: str) -> str | None:
    if not artifact_id:
        return None
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "artifact"
        try:
            download_artifact(artifact_store=storages.artifacts, file_path=str(path), artifact_id=str(artifact_id))
        except Exception as exc:  # the store raises its own not-found types
            raise RecordError(
                f"trial {number}: artifact {key}={artifact_id} not found in {storages.artifact_dir} "
                f"({type(exc).__name__}); pass the study's --artifacts DIR"
            ) from None
        return path.read_text(encoding="utf-8")


def _iso(t: dt.datetime | None) -> str | None:
    return t.isoformat(timespec="seconds") if t is not None else None


def study_summary(storages: Storages, study_name: str) -> dict[str, Any]:
    """Counts by state, the best trial, and throughput over the study's wall span (JSON-ready).

    Throughput: finished trials (COMPLETE, PRUNED, FAIL) per hour and frames simulated per second
    (user attr ``frames_simulated``), both over the span from the first trial's start to the last
    finish — wall time of the whole study, all workers together, pauses between launches included.
    No rates (None) until a trial has run to its end (COMPLETE or PRUNED: failures alone, often
    instant, say nothing of speed) over a span of at least ``MIN_RATE_SPAN_S``.
    """
    study = read_study(storages, study_name)
    trials = study.trials
    counts = {state: 0 for state in STATES}
    for t in trials:
        counts[t.state] += 1
    finished = study.with_states(*FINISHED_STATES)
    starts = [t.datetime_start for t in trials if t.datetime_start is not None]
    ends = [t.datetime_complete for t in finished if t.datetime_complete is not None]
    first = min(starts) if starts else None
    last = max(ends) if ends else None
    span = (last - first).total_seconds() if first is not None and last is not None else 0.0
    frames = sum(int(t.user_attrs.get(keys.FRAMES_SIMULATED, 0) or 0) for t in finished)
    rated = span >= MIN_RATE_SPAN_S and counts["COMPLETE"] + counts["PRUNED"] > 0
    best = study.best
    best_out: dict[str, Any] | None = None
    if best is not None:
        reached = (best.datetime_complete - first).total_seconds() if best.datetime_complete and first else None
        best_out = {"number": best.number, "value": best.value, "params": dict(best.params), "reached_s": reached}
    done = counts["COMPLETE"] + counts["PRUNED"]
    return {
        "study": study_name,
        "storage": storages.url,
        "direction": study.direction,
        "n_trials": len(trials),
        "states": counts,
        "prune_rate": counts["PRUNED"] / done if done else None,
        "best": best_out,
        "first_start": _iso(first),
        "last_finish": _iso(last),
        "wall_seconds": span,
        "trials_per_hour": len(finished) / span * 3600.0 if rated else None,
        keys.FRAMES_SIMULATED: frames,
        "frames_per_second": frames / span if rated else None,
    }


def _best(study: optuna.Study) -> FrozenTrial | None:
    try:
        return study.best_trial
    except ValueError:  # no COMPLETE trial yet
        return None


def _record(trial: TrialRecord) -> dict[str, Any]:
    attrs = trial.user_attrs
    out: dict[str, Any] = {
        "number": trial.number,
        "state": trial.state,
        "value": trial.value,
        "params": dict(trial.params),
        "datetime_start": _iso(trial.datetime_start),
        "datetime_complete": _iso(trial.datetime_complete),
        "duration_s": trial.duration_s,
    }
    out.update({k: attrs[k] for k in _RECORD_ATTRS if k in attrs})
    out[keys.CURVE] = attrs.get(keys.CURVE, [])
    return out


def trial_record(storages: Storages, study_name: str, number: int) -> dict[str, Any]:
    """Trial ``number``'s record: state, value, params and the contract's user attrs (JSON-ready)."""
    return _record(_numbered(read_study(storages, study_name), number))


def best_trial_record(storages: Storages, study_name: str) -> dict[str, Any]:
    """The best COMPLETE trial's record; ``RecordError`` when the study has none yet."""
    best = read_study(storages, study_name).best
    if best is None:
        raise RecordError(f"study '{study_name}' in '{storages.url}': no COMPLETE trial yet; nothing to show")
    return _record(best)


def kept_rungs(user_attrs: Mapping[str, Any]) -> list[tuple[int, float]]:
    """(budget, official score) of each rung of a ladder trial whose net was kept (``artifact_rung_nets``) and
    scored with its ruleset's official protocol; pruned trials' rungs included."""
    from sim.protocols import OFFICIAL

    kept = {str(b) for b in user_attrs.get(keys.ARTIFACT_RUNG_NETS) or {}}
    if not kept or user_attrs.get(keys.OFFICIAL_PROTOCOL) not in OFFICIAL.values():
        return []
    return [(int(r[keys.BUDGET]), float(r[keys.SCORE])) for r in user_attrs.get(keys.RUNGS) or []
            if str(r.get(keys.BUDGET)) in kept and r.get(keys.SCORE) is not None]  # fmt: skip


def scored_nets(user_attrs: Mapping[str, Any], value: float | None, complete: bool) -> list[tuple[float, int | None]]:
    """(score, budget) of every net a trial trained and scored officially: its kept rungs (``kept_rungs``) and, when
    it is COMPLETE, its value (budget None: its top)."""
    found: list[tuple[float, int | None]] = [(score, budget) for budget, score in kept_rungs(user_attrs)]
    if complete and value is not None:
        found.append((float(value), None))
    return found


def net_rank(score: float, budget: int | None, number: int) -> tuple[float, int, int]:
    """Sort key of a scored net (higher is better): the score, then a trial's value (``budget`` None) over a
    rung's, then the earlier trial."""
    return (score, int(budget is None), -number)


def best_net(study: StudyRecord) -> dict[str, Any] | None:
    """The best net the study trained and scored officially: over every COMPLETE trial's value and every kept
    rung of every ladder trial (``kept_rungs``), the highest score (``net_rank``); None before any.

    A rung is a fresh, complete training at its budget, scored with the official protocol, and its net is kept
    (``net_rung_<B>.json``): it is a net one could submit, like a model checkpoint kept for its evaluation score.
    Returns ``trial``, ``budget`` (None: the trial's value), ``score``, ``state``, ``seed`` (the one that net
    trained from: its rung's own under ``[ladder] reseed``), ``official_protocol`` and ``epsilon_test_time`` (what
    it was scored with: the rung's choice under ``[ladder] epsilon_test_grid``, else the trial config's) and
    ``lineage`` (``lineage``: the nets it was refined from, [] for a fresh training).
    """
    best: tuple[tuple[float, int, int], dict[str, Any]] | None = None
    for trial in study.trials:
        attrs = trial.user_attrs
        for score, budget in scored_nets(attrs, trial.value, trial.state == "COMPLETE"):
            rank = net_rank(score, budget, trial.number)
            if best is None or rank > best[0]:
                best = (rank, {"trial": trial.number, "budget": budget, "score": score, "state": trial.state,
                               "seed": _rung_seed(attrs, budget),
                               "official_protocol": attrs.get(keys.OFFICIAL_PROTOCOL),
                               "epsilon_test_time": _rung_epsilon(attrs, budget)})  # fmt: skip
    if best is not None:
        best[1]["lineage"] = lineage(study, best[1]["trial"])
    return None if best is None else best[1]


def lineage(study: StudyRecord, number: int) -> list[dict[str, Any]]:
    """The nets trial ``number`` was refined from (``refine_of``, ``[study] refine_share``), its parent first and the
    fresh training they all started from last; [] for a net trained from fresh weights."""
    out: list[dict[str, Any]] = []
    seen = {number}
    parent = study.trials[number].user_attrs.get(keys.REFINE_OF) if 0 <= number < len(study.trials) else None
    while isinstance(parent, Mapping) and isinstance(parent.get("trial"), int):
        out.append({"trial": parent["trial"], "budget": parent.get("budget"), "score": parent.get("score")})
        if parent["trial"] in seen or not 0 <= parent["trial"] < len(study.trials):
            break  # a damaged record: never loop
        seen.add(parent["trial"])
        parent = study.trials[parent["trial"]].user_attrs.get(keys.REFINE_OF)
    return out


def _rung_epsilon(attrs: Mapping[str, Any], budget: int | None) -> Any:
    """The ε_test the trial's net at ``budget`` (None: its value's) was scored with: the rung's chosen one under
    ``[ladder] epsilon_test_grid``, else the trial config's."""
    from autotune.search.ladder import rung_epsilon

    chosen = None if budget is None else rung_epsilon(attrs.get(keys.RUNGS), budget)
    if chosen is not None:
        return chosen
    config = attrs.get(keys.CONFIG)
    return config.get("epsilon_test_time") if isinstance(config, Mapping) else None


def _rung_seed(attrs: Mapping[str, Any], budget: int | None) -> Any:
    """The seed the trial's net at ``budget`` trained from (None: its value's): the rung's recorded seed, else
    the trial's (rungs stored before they recorded one all trained from it)."""
    if budget is not None:
        for r in attrs.get(keys.RUNGS) or []:
            if r.get(keys.BUDGET) == budget and r.get(keys.SEED) is not None:
                return r[keys.SEED]
    return attrs.get(keys.SEED)


def _numbered(study: StudyRecord, number: int) -> TrialRecord:
    trials = study.trials
    if not 0 <= number < len(trials):
        raise RecordError(
            f"study '{study.name}': no trial {number} (trials are numbered 0 … {len(trials) - 1})"
            if trials
            else f"study '{study.name}': no trial {number} (the study has no trials)"
        )
    trial = trials[number]
    assert trial.number == number
    return trial


def export_trial(storages: Storages, study_name: str, number: int, out_dir: str | Path) -> dict[str, Path]:
    """Write trial ``number``'s ``net.json``, ``net.config.json`` and ``net.js`` into ``out_dir``.

    The net comes from the trial's ``artifact_net_json`` artifact and ``net.js`` from
    ``artifact_net_js`` (regenerated from the net and settings when that one is absent);
    ``net.config.json`` is the net's DeepTraffic settings in the format ``autotune train`` writes
    (``write_net``), rebuilt from the trial's stored ``config``.
    """
    return _export(storages, _numbered(read_study(storages, study_name), number), out_dir)


def export_best(storages: Storages, study_name: str, out_dir: str | Path) -> dict[str, Path]:
    """``export_trial`` of the best COMPLETE trial."""
    best = read_study(storages, study_name).best
    if best is None:
        raise RecordError(f"study '{study_name}' in '{storages.url}': no COMPLETE trial yet; nothing to export")
    return _export(storages, best, out_dir)


def export_best_net(storages: Storages, study_name: str, out_dir: str | Path) -> dict[str, Path]:
    """Write the study's ``best_net`` — a COMPLETE trial's net or a kept rung's — as ``export_trial`` does; a
    rung's ``net.config.json`` and ``net.js`` carry that rung's settings (its budget and the ε schedule scaled
    to it and the ε_test it chose, ``autotune.search.ladder.trained_rung_config``)."""
    study = read_study(storages, study_name)
    found = best_net(study)
    if found is None:
        raise RecordError(f"study '{study_name}' in '{storages.url}': no scored net yet; nothing to export")
    return _export(storages, study.trials[found["trial"]], out_dir, budget=found["budget"])


def stored_net(storages: Storages, trial: TrialRecord, budget: int | None = None) -> tuple[ConvNet, TrainConfig]:
    """Trial ``trial``'s stored net (``budget`` None: its value's; else its kept rung's) and the ``TrainConfig`` it
    was scored with (a rung's: its budget, the ε schedule scaled to it and the ε_test it chose,
    ``autotune.search.ladder.trained_rung_config``); ``RecordError`` when either is not stored."""
    from autotune import TrainConfig, loads_net
    from autotune.search.ladder import trained_rung_config

    text = net_text(storages, trial.number, trial.user_attrs, budget)
    if keys.CONFIG not in trial.user_attrs:
        raise RecordError(f"trial {trial.number}: no training config stored (user attr {keys.CONFIG} missing)")
    net = loads_net(text, where=f"trial {trial.number} net.json")
    config = TrainConfig.from_mapping(trial.user_attrs[keys.CONFIG])
    rungs = trial.user_attrs.get(keys.RUNGS)
    return net, (config if budget is None else trained_rung_config(config, budget, rungs))


def _export(storages: Storages, trial: TrialRecord, out_dir: str | Path, budget: int | None = None) -> dict[str, Path]:
    from autotune import export_netjs, write_net

    net, config = stored_net(storages, trial, budget)
    settings = config.settings
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {"net.json": out / "net.json", "net.config.json": out / "net.config.json", "net.js": out / "net.js"}
    write_net(paths["net.json"], net, settings)  # net.json + net.config.json, as `autotune train` writes them
    netjs = artifact_text(storages, trial, keys.ARTIFACT_NET_JS) if budget is None else None
    paths["net.js"].write_text(netjs if netjs is not None else export_netjs(net, settings), encoding="utf-8")
    return paths


def format_summary(summary: dict[str, Any]) -> Sequence[str]:
    """``study_summary`` as the lines ``autotune status`` prints."""
    s = summary["states"]
    lines = [
        f"study {summary['study']} ({summary['storage']}): {summary['n_trials']} trials — "
        f"{s['COMPLETE']} complete, {s['PRUNED']} pruned, {s['FAIL']} failed, {s['RUNNING']} running, "
        f"{s['WAITING']} waiting"
    ]
    best = summary["best"]
    if best is None:
        lines.append("best: no complete trial yet")
    else:
        when = f" after {best['reached_s'] / 60:.1f} min" if best["reached_s"] is not None else ""
        lines.append(f"best: trial {best['number']}, {best['value']:.2f} mph{when}")
    if summary["trials_per_hour"] is not None:
        prune = f", prune rate {summary['prune_rate']:.0%}" if summary["prune_rate"] is not None else ""
        lines.append(
            f"throughput: {summary['trials_per_hour']:.1f} trials/h, {summary['frames_per_second']:,.0f} frames/s "
            f"over {summary['wall_seconds'] / 60:.1f} min ({summary['first_start']} → {summary['last_finish']}){prune}"
        )
    elif s["COMPLETE"] + s["PRUNED"] == 0:
        failed = f" ({s['FAIL']} failed)" if s["FAIL"] else ""
        lines.append(f"throughput: no trial has finished yet{failed}, so no rates")
    else:
        lines.append(f"throughput: the finished trials span {summary['wall_seconds']:.1f} s, too short for rates")
    return lines


# --------------------------------------------------------------------------------------------
# reproducing a trial's score
# --------------------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Reproduction:
    """A trial's stored official score next to the one obtained again (by re-scoring or retraining)."""

    study: str
    number: int
    stored: float
    """The trial's value: its official score as the study recorded it [mph]."""
    reproduced: float
    """The score obtained now [mph]."""
    protocol: str
    """The official protocol both scores come from."""
    seed: int
    """The trial's training seed."""
    how: str
    """``"rescore"`` (the stored net evaluated again) or ``"retrain"`` (trained again from the seed)."""
    wall_seconds: float
    """Time the reproduction took."""

    @property
    def identical(self) -> bool:
        """True when the scores are bit-identical (the objective is deterministic given the seed)."""
        return self.stored == self.reproduced

    def to_json(self) -> dict[str, Any]:
        return {**dataclasses.asdict(self), "identical": self.identical}


def _complete_trial(storages: Storages, study_name: str, number: int) -> tuple[StudyRecord, TrialRecord]:
    study = read_study(storages, study_name)
    trial = _numbered(study, number)
    if trial.state != "COMPLETE" or trial.value is None:
        raise RecordError(
            f"study '{study_name}': trial {number} is {trial.state}; only COMPLETE trials have an official "
            "score to reproduce"
        )
    for key in (keys.CONFIG, keys.SEED):
        if key not in trial.user_attrs:
            raise RecordError(f"study '{study_name}': trial {number} has no stored {key} (user attr '{key}')")
    return study, trial


def rescore_trial(storages: Storages, study_name: str, number: int) -> Reproduction:
    """Evaluate trial ``number``'s stored network again with its official protocol (exact, seconds)."""
    import time

    from autotune import TrainConfig, evaluate_official, loads_net, official_protocol

    _, trial = _complete_trial(storages, study_name, number)
    config = TrainConfig.from_mapping(trial.user_attrs[keys.CONFIG])
    protocol = str(trial.user_attrs.get(keys.OFFICIAL_PROTOCOL) or official_protocol(config))
    text = artifact_text(storages, trial, keys.ARTIFACT_NET_JSON)
    if text is None:
        raise RecordError(f"trial {number}: no trained network stored (user attr {keys.ARTIFACT_NET_JSON} missing)")
    t0 = time.perf_counter()
    ev = evaluate_official(loads_net(text, where=f"trial {number} net.json"), config, protocol=protocol)
    assert trial.value is not None
    return Reproduction(
        study_name, number, float(trial.value), float(ev.median_site), protocol, int(trial.user_attrs[keys.SEED]),
        "rescore", time.perf_counter() - t0,
    )  # fmt: skip


def retrain_trial(storages: Storages, study_name: str, number: int) -> Reproduction:
    """Train trial ``number`` again — its stored config and seed, the study's report settings — and score it.

    The call is the objective's own (``objective.run_trial`` with the task the driver built, never
    pruned, no time limit), so a deterministic learner gives the stored score bit for bit; a weight soup
    (``soup_of``) averages its ingredients' stored nets again and is scored, training nothing. The caller owns the
    process settings (``configure_process``) as a worker does.
    """
    import time

    from autotune.search.objective import COMPLETE, TrialTask, run_trial

    study, trial = _complete_trial(storages, study_name, number)
    evaluation = _evaluation(study)
    parent = trial.user_attrs.get(keys.REFINE_OF)  # a refinement run trains on from its parent's stored net
    ingredients = trial.user_attrs.get(keys.SOUP_OF)  # a weight soup averages its ingredients' stored nets again
    if ingredients is not None:
        init_net: str | None = soup_net(storages, study, ingredients, keys.SEED_SOUP_OF in trial.user_attrs)
    else:
        init_net = None if parent is None else parent_net(storages, study, parent)
    task = TrialTask(
        number=number,
        config=trial.user_attrs[keys.CONFIG],
        seed=int(trial.user_attrs[keys.SEED]),
        report_points=int(evaluation.get("report_points", TrialTask.report_points)),
        quick_runs=int(evaluation.get("quick_runs", TrialTask.quick_runs)),
        quick_frames=int(evaluation.get("quick_frames", TrialTask.quick_frames)),
        final_protocol=str(trial.user_attrs.get(keys.OFFICIAL_PROTOCOL) or evaluation.get("final_protocol") or ""),
        timeout_s=None,
        init_net=init_net,
        evaluate_only=ingredients is not None,
    )
    t0 = time.perf_counter()
    outcome = run_trial(task, lambda step, frames, score: False)
    if outcome.state != COMPLETE or outcome.value is None:
        cause = (outcome.cause or "").strip().splitlines()
        raise RecordError(
            f"study '{study_name}': retraining trial {number} ended {outcome.state} ({cause[-1] if cause else '?'})"
        )
    assert trial.value is not None
    return Reproduction(
        study_name, number, float(trial.value), float(outcome.value), str(outcome.attrs[keys.OFFICIAL_PROTOCOL]),
        task.seed, "retrain", time.perf_counter() - t0,
    )  # fmt: skip


def parent_net(storages: Storages, study: StudyRecord, refine_of: Mapping[str, Any]) -> str:
    """The Net JSON a refinement run trained on from (its ``refine_of``), read from the artifact store."""
    number, budget = int(refine_of["trial"]), refine_of.get("budget")
    return net_text(storages, number, _numbered(study, number).user_attrs, None if budget is None else int(budget))


def soup_net(storages: Storages, study: StudyRecord, ingredients: Sequence[int], stacked: bool = False) -> str:
    """The Net JSON of a weight soup (``soup_of``): the mean weights of its ingredients' stored nets; ``stacked`` (a
    seed soup, ``seed_soup_of``): their ensemble (``stack.stack_nets``, the same mean for nets without hidden layers,
    side by side with them)."""
    from autotune.convnet.netjson import dumps_net, loads_net
    from autotune.convnet.stack import stack_nets
    from autotune.search.soup import average_nets

    nets = [loads_net(parent_net(storages, study, {"trial": int(n), "budget": None}), where=f"trial {n} net.json")
            for n in ingredients]  # fmt: skip
    return dumps_net(stack_nets(nets) if stacked else average_nets(nets))


def _spec_table(study: StudyRecord, table: str) -> dict[str, Any]:
    """A table of the spec the study ran with (the driver stores it as study user attr ``spec``); {} if none."""
    spec = study.user_attrs.get(keys.STUDY_SPEC)
    found = spec.get(table) if isinstance(spec, dict) else None
    return found if isinstance(found, dict) else {}


def _evaluation(study: StudyRecord) -> dict[str, Any]:
    """The [evaluation] table the study ran with."""
    return _spec_table(study, "evaluation")


def study_resources(storages: Storages, study_name: str) -> dict[str, Any]:
    """The [resources] table the study ran with ({} when the study has no stored spec)."""
    return _spec_table(read_study(storages, study_name), "resources")


def race_setup(study_attrs: Mapping[str, Any]) -> tuple[list[int], int]:
    """A study's seed race as stored: its field (entrants' trial numbers, best first; [] before the race) and
    its fresh seeds per round (the spec's ``race_seeds``), from the study's user attrs."""
    spec = study_attrs.get(keys.STUDY_SPEC)
    table = spec.get("study") if isinstance(spec, dict) else None
    seeds = table.get("race_seeds") if isinstance(table, dict) else None
    return [int(n) for n in study_attrs.get(keys.RACE_FIELD) or []], int(seeds or 1)


def race_summary(storages: Storages, study_name: str) -> dict[str, Any] | None:
    """The seed race's standings (``autotune.search.racing``): each entrant's fresh-seed mean ± sd and n.

    Before the race (no field stored yet), a provisional standing (``"provisional": True``): the
    configurations with ``racing.PROVISIONAL_SEEDS`` fresh-seed runs so far, by their mean; None when none has.
    The winner (``racing.standings``) is the finalist ranked first by paired signed ranks, then mean, on the fresh
    seeds every finalist has a result for (``ranked_on`` of them; a run the deadline stopped is left out for all):
    the configuration to retrain, as opposed to the best single net (the leaderboard's number). Once that winner's
    tail falls below a rival of its last round, the rival is the winner row instead (``racing.tail_leader``; not a
    finalist). An entrant raced at a kept rung's budget (``budget``, else None) was selected by that rung's score.
    """
    from autotune.search import racing

    study = read_study(storages, study_name)
    field, seeds_per_round = race_setup(study.user_attrs)
    trials = study.trials
    results: dict[tuple[int, int], float | None] = {}
    for t in trials:
        if keys.RACE_OF in t.user_attrs:
            a = t.user_attrs
            is_result, score = racing.run_result(t.state, t.value, a.get(keys.CAUSE), bool(a.get(keys.RETRYABLE)))
            if is_result:
                results[(int(a[keys.RACE_OF]), int(a[keys.RACE_SEED]))] = score
    budgets = study.user_attrs.get(keys.RACE_BUDGETS) or {}
    if not field:
        return _provisional_summary(trials, results, budgets)
    rows = []
    for st in racing.standings(field, results, seeds_per_round):
        budget = budgets.get(str(st.number))
        selecting = (
            trials[st.number].value if budget is None else dict(kept_rungs(trials[st.number].user_attrs))[budget]
        )
        paired = st.paired_mean
        rows.append({"trial": st.number, "budget": budget, "selecting_value": selecting, "n": len(st.scores),
                     "mean": st.mean if st.scores else None, "sd": st.sd if len(st.scores) > 1 else None,
                     "scores": list(st.scores), "finalist": st.finalist,
                     "ranked_on": len(st.paired) if st.paired else 0,
                     "paired_mean": paired if paired is not None and math.isfinite(paired) else None})  # fmt: skip
    return {"entrants": field, "standings": rows, "winner": rows[0] if rows[0]["n"] else None, "provisional": False}


def _provisional_summary(
    trials: Sequence[TrialRecord], results: Mapping[tuple[int, int], float | None], budgets: Mapping[str, Any]
) -> dict[str, Any] | None:
    """``race_summary`` before the race: the configurations with ``racing.PROVISIONAL_SEEDS`` fresh seeds (seed
    runs, the incumbent's runs) ranked by their mean (``racing.provisional_standings``); None when none has."""
    from autotune.search import racing

    standing = racing.provisional_standings(results)
    if not standing:
        return None
    rows = []
    for st in standing:
        budget = budgets.get(str(st.number))
        attrs = trials[st.number].user_attrs
        rungs = dict(kept_rungs(attrs))
        selecting = trials[st.number].value if budget is None else rungs.get(budget)
        if selecting is None and rungs:  # a pruned trial's seeds (a kept rung's budget) before the race stored it
            selecting = max(rungs.values())
        rows.append({"trial": st.number, "budget": budget, "selecting_value": selecting, "n": len(st.scores),
                     "mean": st.mean, "sd": st.sd if len(st.scores) > 1 else None, "scores": list(st.scores),
                     "finalist": False, "ranked_on": 0, "paired_mean": None})  # fmt: skip
    return {"entrants": [], "standings": rows, "winner": rows[0], "provisional": True}
