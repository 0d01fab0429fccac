"""The crowd as a study: one COMPLETE trial per scored submission, under the search's parameter names.

So that optuna-dashboard and the report read the crowd exactly like an automated study, each
submission's settings are encoded by the search's one encoder (``space.encode``) in the paper's
space (``crowd_spec``: ``lanes_side`` … ``one_minus_gamma`` …, ``n_layers``, ``neurons_i``,
``activation_i``), with ranges from ``sim.fields`` (``distributions``), its value
is the self-reported score and its provenance goes into user attributes. Unscored submissions and
the two whose settings our learner refuses are skipped (Optuna needs a value for a COMPLETE trial;
a FAIL trial would read as "the setting crashed"), and the import says how many and why.
Importing again adds only the submissions not yet in the study. The trials are plain records
(``autotune.search.records``) written through ``autotune.search.enqueue.add_finished``: Optuna stays
inside the search. ``score_own_nets`` scores the human nets with their own weights (exact evaluator).
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import functools
import math
from collections.abc import Callable, Iterable, Sequence
from typing import Any

from autotune.learner.config import TrainConfig
from autotune.search import keys, space
from autotune.search.enqueue import add_finished
from autotune.search.records import Distribution, StudyRecord, TrialRecord, read_study_if_present
from autotune.search.space import DEFAULT_SPACE
from autotune.search.spec import StudySpec, param_bounds, parse_spec
from autotune.search.storage import Storages
from dashboards import crowd_data as cd
from dashboards import provenance as pv
from sim.protocols import OFFICIAL

__all__ = [
    "CROWD_STUDY",
    "REPLAY_STUDY",
    "CROWD_METRIC",
    "REPLAY_METRIC",
    "own_net_attrs",
    "ACTIVATION_CHOICES",
    "ImportResult",
    "crowd_spec",
    "crowd_params",
    "distributions",
    "crowd_trials",
    "import_crowd",
    "crowd_study",
    "score_own_nets",
    "submission_order",
]

CROWD_STUDY = "crowd"
REPLAY_STUDY = "crowd-replay"
CROWD_METRIC = (
    "self-reported score [mph]: claimed by the author, not measured (engine: engine_version; kind: score_kind; "
    "measured own-weight score, where there is one: own_net_score)"
)
REPLAY_METRIC = (
    "replayed score [mph], measured: the crowd setting retrained by our learner in its own engine, site median of "
    "that engine's official protocol"
)
ACTIVATION_CHOICES = ("relu", "tanh", "sigmoid", "maxout", "linear", "svm")


@functools.cache
def crowd_spec() -> StudySpec:
    """The space the crowd is encoded in (``space.encode``): the paper's (``space.DEFAULT_SPACE``), so the crowd and
    the automated studies share parameter names."""
    return parse_spec({"study": {"name": CROWD_STUDY, "n_trials": 1}, "space": DEFAULT_SPACE}, source="crowd")


def crowd_params(config: TrainConfig) -> dict[str, Any]:
    """A configuration's params in the crowd study: ``space.encode`` in ``crowd_spec``, its active ones only
    (``space.active``: a record shows the layers a net has, not the fixed shape's unused slots)."""
    return space.active(space.encode(crowd_spec(), config))


def distributions(all_params: Iterable[dict[str, Any]]) -> dict[str, Distribution]:
    """One distribution per parameter name, covering every value given.

    The range is the setting's own in ``sim.fields`` (``spec.param_bounds``), so it holds every valid
    config whatever the crowd holds; on a log scale where the paper's space samples it so (starting
    where that space starts when the setting's range starts at 0), unless a value is ≤ 0. The
    open-ended layout takes the paper space's largest values. Widened, if need be, to hold every value.
    """
    values: dict[str, list[Any]] = {}
    for params in all_params:
        for name, value in params.items():
            values.setdefault(name, []).append(value)
    dims = crowd_spec().dimensions
    out: dict[str, Distribution] = {}
    for name, vals in values.items():
        base = name.rsplit("_", 1)[0] if name.startswith(("neurons_", "activation_")) else name
        if base == "activation":
            out[name] = Distribution("categorical", choices=ACTIVATION_CHOICES)
            continue
        kind, low, high = param_bounds(base)
        paper = dims[base]
        assert paper.low is not None and paper.high is not None
        log = paper.log and min(vals) > 0
        low = paper.low if log and low <= 0 else low
        low, high = min(low, *vals), max(paper.high if high is None else high, *vals)
        if kind == "int":
            out[name] = Distribution("int", int(low), int(high), log, 1)
        else:
            out[name] = Distribution("float", float(low), float(high), log)
    return out


def submission_order(subs: Sequence[cd.Submission]) -> list[cd.Submission]:
    """Submissions in the order people made them: by version date (undated last), then id."""
    return sorted(subs, key=lambda s: (s.version_date is None, s.version_date or dt.date.min, s.id))


@dataclasses.dataclass(frozen=True)
class ImportResult:
    """What ``import_crowd`` did: trials added, already present, and skipped submissions with the reason."""

    study_name: str
    added: int
    existing: int
    skipped: dict[str, str]


def _user_attrs(sub: cd.Submission, config: TrainConfig, own: dict[str, Any] | None) -> dict[str, Any]:
    attrs: dict[str, Any] = {
        keys.SOURCE: keys.SOURCE_CROWD,
        keys.CROWD_ID: sub.id,
        "id": sub.id,
        "repo": sub.repo,
        "path": sub.path,
        "commit": sub.commit,
        "version_date": sub.version_date.isoformat() if sub.version_date else None,
        "score_kind": sub.score_kind,
        "score_confidence": sub.score_confidence,
        "value_is": f"{pv.KIND_LABEL[str(sub.score_kind)]}: self-reported by the author, not measured "
        f"({pv.ENGINE_LABEL[sub.engine_version]}, {pv.agents_label(sub.engine_version, sub.other_agents)})",
        "config_hash": sub.config_hash,
        "score_source": sub.score_source,
        keys.ENGINE_VERSION: sub.engine_version,
        "trainer_method": sub.settings.method,
        "hidden_layers": sub.hidden_layers,
        "is_default_template": sub.is_default_template,
        "same_config_as": sub.same_config_as,
        "has_weights": sub.has_weights,
        "in_nets_dir": sub.in_nets_dir,
        keys.CONFIG: config.to_mapping(),
        keys.SETTINGS: config.to_deepqlearn(),
        keys.INPUT_SIZE: config.net_inputs,
        keys.NUM_STATES: config.num_states,
        keys.PARAM_COUNT: config.param_count,
        keys.FRAMES_SIMULATED: cd.frames_estimate(sub) or cd.FRAMES_PER_ITERATION * config.train_iterations,
        keys.OFFICIAL_PROTOCOL: OFFICIAL[sub.engine_version],
    }
    if own is not None:
        attrs[keys.OWN_NET_SCORE] = own["score"]
        attrs[keys.OWN_NET_PROTOCOL] = own.get("protocol")
    return attrs


def crowd_trials(
    subs: Sequence[cd.Submission] | None = None, own_net_scores: dict[str, dict[str, Any]] | None = None
) -> tuple[list[TrialRecord], dict[str, str]]:
    """COMPLETE trials for the scored submissions in submission order, and {id: reason} for those skipped."""
    subs = cd.load_submissions() if subs is None else subs
    kept: list[tuple[cd.Submission, TrainConfig, dict[str, Any]]] = []
    skipped: dict[str, str] = {}
    for sub in submission_order(subs):
        if sub.reported_score_mph is None:
            skipped[sub.id] = "no reported score"
            continue
        try:
            config = cd.train_config(sub)
        except cd.CrowdDataError as exc:
            skipped[sub.id] = str(exc).removeprefix(f"{sub.id}: ")
            continue
        kept.append((sub, config, crowd_params(config)))
    dists = distributions(p for _s, _c, p in kept)
    trials = []
    now = dt.datetime.now()  # Optuna needs a start time; undated rows get the import's (version_date stays None)
    for number, (sub, config, params) in enumerate(kept):
        when = dt.datetime.combine(sub.version_date, dt.time()) if sub.version_date else now
        trials.append(
            TrialRecord(
                number=number,
                state="COMPLETE",
                value=sub.reported_score_mph,
                params=params,
                distributions={k: dists[k] for k in params},
                user_attrs=_user_attrs(sub, config, (own_net_scores or {}).get(sub.id)),
                datetime_start=when,
                datetime_complete=when,
            )
        )
    return trials, skipped


def import_crowd(
    storages: Storages | None,
    study_name: str = CROWD_STUDY,
    own_net_scores: dict[str, dict[str, Any]] | None = None,
) -> tuple[StudyRecord, ImportResult]:
    """Write the crowd into ``study_name`` (created if absent, direction maximize); adds only missing submissions.

    ``storages`` None: a study in memory. ``own_net_scores`` ({id: {score, protocol, …}}; default: the
    shipped ``measured.load_own_nets()``) are merged into the study's ``own_net_scores`` user attribute
    and set on the trials created now. The study's metric name says that its values are claims.
    Returns the study as it stands afterwards and what the import did.
    """
    if own_net_scores is None:
        from dashboards import measured

        own_net_scores = own_net_attrs(measured.load_own_nets())
    before = read_study_if_present(storages, study_name) if storages is not None else None
    present = {t.user_attrs.get(keys.CROWD_ID) for t in before.trials} if before is not None else set()
    trials, skipped = crowd_trials(own_net_scores=own_net_scores)
    new = [t for t in trials if t.user_attrs[keys.CROWD_ID] not in present]
    attrs: dict[str, Any] = {keys.SOURCE: keys.SOURCE_CROWD, keys.SKIPPED: skipped}
    if own_net_scores:
        stored = before.user_attrs.get(keys.OWN_NET_SCORES, {}) if before is not None else {}
        attrs[keys.OWN_NET_SCORES] = {**stored, **own_net_scores}
    study = add_finished(storages, study_name, new, attrs, metric_name=CROWD_METRIC)
    return study, ImportResult(study_name, len(new), len(trials) - len(new), skipped)


def own_net_attrs(scores: Iterable[Any]) -> dict[str, dict[str, Any]]:
    """``measured.OwnNetScore``s as the study attribute ``own_net_scores`` holds them ({id: {score, …}})."""
    return {
        s.crowd_id: {
            "score": s.score, "protocol": s.protocol, "mean": s.mean, "std": s.std, "runs": s.runs,
            "other_agents": s.other_agents, "seed": s.seed,
        }
        for s in scores
    }  # fmt: skip


def crowd_study(storages: Storages | None = None) -> StudyRecord:
    """The crowd study from ``storages`` if it holds one named 'crowd', else built in memory from the package data."""
    stored = read_study_if_present(storages, CROWD_STUDY) if storages is not None else None
    return stored if stored is not None else import_crowd(None, CROWD_STUDY)[0]


def score_own_nets(progress: Callable[[str], None] | None = None) -> dict[str, dict[str, Any]]:
    """The 25 human nets scored now with their own weights, engine and official protocol (exact evaluator).

    ``progress`` gets one line per net. The same numbers as the shipped ``measured.load_own_nets()``.
    """
    from dashboards import measured

    def show(s: measured.OwnNetScore) -> None:
        if progress is not None:
            progress(f"{s.crowd_id}: {s.score:.2f} mph ({s.protocol}, {s.seconds:.1f} s)")

    return own_net_attrs(measured.score_own_nets(progress=show))


def finite(value: Any) -> bool:
    """A real, finite number (not None, NaN or a bool)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
