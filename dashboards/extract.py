"""Plot data extracted from studies (automated or crowd) and the shipped measurements, as plain values.

Everything a report panel shows is computed here and tested as values; ``dashboards.figures``
only draws it. A panel that cannot be computed (too few trials, a constant setting) gets an
``Empty`` with the reason, which the report prints instead of an empty figure.

``study_data`` is the one place a study is read — as plain records from ``autotune.search.records``
(``read_study``; no Optuna object reaches the reports). Trials are read through the trial-record
contract (``autotune.search.keys``): the value is the official score (the crowd study: the
self-reported score), the real settings are in the ``config`` user attribute (parameters, in sampling
coordinates, are the fallback), and the compute spent is ``frames_simulated``. Every point carries
what its score is (``dashboards.provenance``): engine, other agents, score kind and confidence; crowd
rows take their configuration hash and repository from the packaged CSV by crowd id.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from autotune.search import keys
from autotune.search.records import FINISHED_STATES, StudyRecord, TrialRecord
from autotune.search.spec import EPSILON_TEST_SHIFTED, unshift_epsilon
from dashboards import provenance as pv

__all__ = [
    "HYPERPARAMETERS",
    "LOG_AXES",
    "FEATURES",
    "Empty",
    "TrialPoint",
    "StudyData",
    "Points",
    "Progress",
    "SizeScatter",
    "Panel",
    "ComputeCurve",
    "TsneMap",
    "Importances",
    "ClaimRow",
    "study_data",
    "points",
    "progress",
    "size_scatter",
    "hyperparameter_panels",
    "compute_curve",
    "tsne_map",
    "importances",
    "replay_comparison",
    "own_net_rows",
    "replay_table_rows",
]

# the paper's per-hyperparameter panels, in the order (real values, not sampling coordinates)
HYPERPARAMETERS = (
    "lanes_side",
    "patches_ahead",
    "patches_behind",
    "temporal_window",
    "other_agents",
    "gamma",
    "learning_rate",
    "l2_decay",
    "batch_size",
    "experience_size",
    "train_iterations",
)
LOG_AXES = frozenset({"learning_rate", "batch_size", "experience_size", "train_iterations"})
FEATURES = (*(h for h in HYPERPARAMETERS if h != "other_agents"), "n_layers", "param_count", "engine", "other_agents")
"""Inputs of the importances: the stored config's settings, the net's size, the engine (v2 = 1) and other agents."""


@dataclasses.dataclass(frozen=True)
class Empty:
    """A panel with nothing to draw, and why (shown to the reader instead of a figure)."""

    reason: str


@dataclasses.dataclass(frozen=True)
class TrialPoint:
    """One finished trial as the report reads it."""

    number: int
    """Optuna trial number (the crowd: submission order)."""
    state: str
    """COMPLETE, PRUNED or FAIL."""
    value: float | None
    """The score [mph] (its kind says what it is); None unless COMPLETE with a finite value."""
    label: str
    """Hover label: the crowd id, else 'trial N'."""
    settings: dict[str, float]
    """Real values of ``HYPERPARAMETERS`` present in the trial."""
    param_count: int | None
    """Weights + biases of the trial's net."""
    n_layers: int | None
    """Hidden layers with neurons."""
    frames: int | None
    """Frames simulated for the trial (training + evaluation; the crowd: 30·trainIterations)."""
    crowd_id: str | None
    """The crowd submission the trial replays or records."""
    engine: str
    """Engine the score comes from ('v1' or 'v2')."""
    other_agents: int | None
    """Other agents on the road (None in v1, which has none)."""
    kind: str
    """Score kind (``provenance.KIND_LABEL``): a crowd claim's score_kind, or how it was measured."""
    confidence: str
    """The crowd's score_confidence (high, medium, low); 'exact' for a measured score."""
    config_key: str
    """The configuration: identical settings share it (the crowd: config_hash; else the stored config)."""
    repo: str | None
    """The crowd row's repository (None for our own trials)."""
    refined_from: int | None = None
    """A refinement run (``[study] refine_share``): the trial whose net it trained on from. Its score is that net's,
    trained on: a best single net, never a measure of its settings."""

    def custom(self) -> list[str]:
        """Its ``customdata`` row (``provenance.CUSTOMDATA``)."""
        return [
            self.label,
            pv.ENGINE_LABEL[self.engine],
            pv.agents_label(self.engine, self.other_agents),
            pv.KIND_LABEL[self.kind],
            self.confidence,
        ]


@dataclasses.dataclass(frozen=True)
class StudyData:
    """A study's finished trials in trial order, with its name, source ('autotune', 'crowd', 'crowd-replay')."""

    name: str
    source: str
    trials: tuple[TrialPoint, ...]
    user_attrs: dict[str, Any]
    skipped: dict[int, str]
    """Finished trials left out (trial number → why: no engine or score kind recorded)."""

    @property
    def scored(self) -> list[TrialPoint]:
        """Trials with a score."""
        return [t for t in self.trials if t.value is not None]

    @property
    def settings_scored(self) -> list[TrialPoint]:
        """Trials whose score measures their settings: ``scored`` without refinement runs (``refined_from``), which
        train on from another trial's net."""
        return [t for t in self.scored if t.refined_from is None]

    @property
    def engines(self) -> list[str]:
        """Engines of its scored trials, v1 first."""
        return [e for e in pv.ENGINES if any(t.engine == e for t in self.scored)]

    @property
    def kinds(self) -> list[str]:
        """Score kinds of its scored trials."""
        return [k for k in pv.KIND_LABEL if any(t.kind == k for t in self.scored)]


@dataclasses.dataclass(frozen=True)
class Points:
    """Scored points (x, y) with their provenance: parallel lists, one entry per point."""

    x: list[float]
    y: list[float]
    trials: list[TrialPoint]

    def groups(self) -> dict[tuple[str, str], list[int]]:
        """(engine, kind) → indices of its points, engines v1 first then kinds in ``KIND_LABEL`` order."""
        out: dict[tuple[str, str], list[int]] = {}
        for e in pv.ENGINES:
            for k in pv.KIND_LABEL:
                idx = [i for i, t in enumerate(self.trials) if t.engine == e and t.kind == k]
                if idx:
                    out[(e, k)] = idx
        return out


@dataclasses.dataclass(frozen=True)
class Progress:
    """Score in trial order, with the running best of each engine (the paper's progress figure)."""

    points: Points
    best: dict[str, tuple[list[int], list[float], list[TrialPoint]]]
    """engine → (trial numbers, best so far among that engine's scores, the trial holding it)."""


@dataclasses.dataclass(frozen=True)
class SizeScatter:
    """Parameter count against score, with the layer count and training iterations for colouring."""

    points: Points
    n_layers: list[int]
    train_iterations: list[float]


@dataclasses.dataclass(frozen=True)
class Panel:
    """One hyperparameter against score."""

    name: str
    points: Points
    log_x: bool


@dataclasses.dataclass(frozen=True)
class ComputeCurve:
    """Best score against cumulative frames simulated, per engine."""

    best: dict[str, tuple[list[int], list[float], list[TrialPoint]]]
    """engine → (cumulative frames of the side after each of its trials, best so far, the trial holding it)."""
    kinds: dict[str, list[str]]
    """engine → the score kinds its best is taken over."""


@dataclasses.dataclass(frozen=True)
class TsneMap:
    """A joint 2-D t-SNE embedding of both studies' settings (standardised, log-scaled where wide)."""

    x: list[float]
    y: list[float]
    score: list[float]
    source: list[str]
    trials: list[TrialPoint]
    features: list[str]
    seed: int


@dataclasses.dataclass(frozen=True)
class Importances:
    """Setting importances of a study (normalised to sum 1), largest first, and what they were computed on."""

    names: list[str]
    values: list[float]
    evaluator: str
    n: int
    """Configurations (identical settings once)."""
    engines: list[str]
    kinds: list[str]


@dataclasses.dataclass(frozen=True)
class ClaimRow:
    """A crowd score claimed by its author against the score we measured for it."""

    crowd_id: str
    engine: str
    other_agents: int | None
    claimed: float
    claim_kind: str
    claim_confidence: str
    measured: float
    """Measured score [mph]: own weights, or the mean over replay seeds."""
    measured_kind: str
    """``provenance.OWN_WEIGHTS`` or ``provenance.REPLAYED``."""
    sd: float | None
    """sd over seeds (replays with ≥ 2 complete seeds), else None."""
    n: int
    """Seeds (replays) or 1 (own weights)."""
    scores: tuple[float, ...] = ()
    """Each seed's score (replays) [mph]."""
    seconds: float | None = None
    """Wall time of the replay's seeds, or of the own-weight evaluation [s]."""
    protocol: str = ""


def _number(value: Any) -> float | None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        return None
    return float(value)


def _settings(trial: TrialRecord) -> dict[str, float]:
    config = trial.user_attrs.get(keys.CONFIG)
    source: dict[str, Any] = dict(config) if isinstance(config, dict) else {}
    for name in HYPERPARAMETERS:
        if name not in source and name in trial.params:
            source[name] = trial.params[name]
    if "gamma" not in source and "one_minus_gamma" in trial.params:
        source["gamma"] = 1.0 - trial.params["one_minus_gamma"]
    if "epsilon_test_time" not in source and EPSILON_TEST_SHIFTED in trial.params:
        source["epsilon_test_time"] = unshift_epsilon(trial.params[EPSILON_TEST_SHIFTED])
    if _engine(trial) == "v1":
        source.pop("other_agents", None)  # v1 has no agents: not "0 agents"
    out = {}
    for name in HYPERPARAMETERS:
        value = _number(source.get(name))
        if value is not None:
            out[name] = value
    return out


def _n_layers(trial: TrialRecord) -> int | None:
    config = trial.user_attrs.get(keys.CONFIG)
    if isinstance(config, dict) and isinstance(config.get("layers"), str):
        return sum(1 for part in config["layers"].split("|") if part and not part.startswith("lrn"))
    if "n_layers" in trial.params:
        return int(trial.params["n_layers"])
    return None


def _engine(trial: TrialRecord) -> str | None:
    config = trial.user_attrs.get(keys.CONFIG)
    engine = config.get("ruleset") if isinstance(config, dict) else None
    engine = engine or trial.user_attrs.get(keys.ENGINE_VERSION)
    return engine if engine in pv.ENGINES else None


def _crowd_rows() -> dict[str, Any]:
    from dashboards import crowd_data

    return {s.id: s for s in crowd_data.load_submissions()}


def _kind(source: str, attrs: Mapping[str, Any], row: Any) -> tuple[str, str] | None:
    """(score kind, confidence) of a trial's value; None when a crowd trial does not say what its score is."""
    if source == keys.SOURCE_CROWD:
        kind = row.score_kind if row is not None else attrs.get("score_kind")
        confidence = row.score_confidence if row is not None else attrs.get("score_confidence")
        if kind not in pv.KIND_LABEL or pv.is_measured(kind):
            return None
        return kind, str(confidence or "not recorded")
    if source == keys.SOURCE_CROWD_REPLAY:
        return pv.REPLAYED, "exact"
    return pv.SEARCHED, "exact"


def _refined_from(attrs: Mapping[str, Any]) -> int | None:
    parent = attrs.get(keys.REFINE_OF)
    return int(parent["trial"]) if isinstance(parent, Mapping) and isinstance(parent.get("trial"), int) else None


def study_data(study: StudyRecord) -> StudyData:
    """The finished trials of ``study`` (COMPLETE, PRUNED, FAIL) as ``TrialPoint``s, in trial order."""
    if study.direction != "MAXIMIZE":
        raise ValueError(f"study {study.name!r} minimizes; reports compare scores (maximized)")
    all_trials = study.trials
    sources = {t.user_attrs.get(keys.SOURCE) for t in all_trials}
    auto = keys.SOURCE_AUTOTUNE
    source = str(study.user_attrs.get(keys.SOURCE) or (sources.pop() if len(sources) == 1 else auto) or auto)
    crowd_rows = _crowd_rows() if source in (keys.SOURCE_CROWD, keys.SOURCE_CROWD_REPLAY) else {}
    points = []
    skipped: dict[int, str] = {}
    for t in all_trials:
        if t.state not in FINISHED_STATES:
            continue
        attrs = t.user_attrs
        engine = _engine(t)
        if engine is None:
            skipped[t.number] = "no engine recorded (user attr config.ruleset)"
            continue
        value = _number(t.value) if t.state == "COMPLETE" else None
        crowd_id = attrs.get(keys.CROWD_ID)
        row = crowd_rows.get(crowd_id) if crowd_id else None
        config = attrs.get(keys.CONFIG)
        agents = config.get("other_agents") if isinstance(config, dict) else attrs.get("other_agents")
        kind_confidence = _kind(source, attrs, row)
        if kind_confidence is None:
            skipped[t.number] = "a crowd trial without a score kind (user attr score_kind)"
            continue
        kind, confidence = kind_confidence
        pc = _number(attrs.get(keys.PARAM_COUNT))
        frames = _number(attrs.get(keys.FRAMES_SIMULATED))
        key = row.config_hash if row is not None else json.dumps(config, sort_keys=True) if config else str(t.params)
        points.append(
            TrialPoint(
                number=t.number,
                state=t.state,
                value=value,
                label=str(crowd_id) if crowd_id else f"trial {t.number}",
                settings=_settings(t),
                param_count=int(pc) if pc is not None else None,
                n_layers=_n_layers(t),
                frames=int(frames) if frames is not None else None,
                crowd_id=str(crowd_id) if crowd_id else None,
                engine=engine,
                other_agents=int(agents)
                if engine == "v2" and agents is not None and _number(agents) is not None
                else None,
                kind=kind,
                confidence=confidence,
                config_key=key,
                repo=row.repo if row is not None else attrs.get("repo"),
                refined_from=_refined_from(attrs),
            )
        )
    return StudyData(study.name, source, tuple(points), dict(study.user_attrs), skipped)


def points(trials: Sequence[TrialPoint], x: Sequence[float]) -> Points:
    """``Points`` of scored trials with the given x values."""
    return Points(x=[float(v) for v in x], y=[float(t.value) for t in trials], trials=list(trials))  # type: ignore[arg-type]


def _running_best(
    trials: Sequence[TrialPoint], xs: Sequence[int]
) -> dict[str, tuple[list[int], list[float], list[TrialPoint]]]:
    out: dict[str, tuple[list[int], list[float], list[TrialPoint]]] = {}
    for engine in pv.ENGINES:
        order: list[int] = []
        best: list[float] = []
        holder: list[TrialPoint] = []
        for t, x in zip(trials, xs, strict=True):
            if t.engine != engine or t.value is None:
                continue
            if not best or t.value > best[-1]:
                best.append(t.value)
                holder.append(t)
            else:
                best.append(best[-1])
                holder.append(holder[-1])
            order.append(x)
        if order:
            out[engine] = (order, best, holder)
    return out


def progress(data: StudyData) -> Progress | Empty:
    """Scores in trial (crowd: submission) order with each engine's running best."""
    scored = data.scored
    if not scored:
        return Empty(f"{data.name}: no scored trial yet")
    return Progress(points(scored, [t.number for t in scored]), _running_best(scored, [t.number for t in scored]))


def size_scatter(data: StudyData) -> SizeScatter | Empty:
    """Parameter count against score (trials that record both)."""
    pts = [t for t in data.settings_scored if t.param_count is not None]
    if not pts:
        return Empty(f"{data.name}: no scored trial records its parameter count")
    return SizeScatter(
        points=points(pts, [t.param_count for t in pts]),  # type: ignore[misc]
        n_layers=[t.n_layers if t.n_layers is not None else -1 for t in pts],
        train_iterations=[t.settings.get("train_iterations", math.nan) for t in pts],
    )


def hyperparameter_panels(data: StudyData) -> dict[str, Panel | Empty]:
    """One panel per hyperparameter of ``HYPERPARAMETERS``: its real value against score."""
    out: dict[str, Panel | Empty] = {}
    for name in HYPERPARAMETERS:
        pts = [t for t in data.settings_scored if name in t.settings]
        if not pts:
            out[name] = Empty(f"{data.name}: {name} not recorded in any scored trial")
            continue
        out[name] = Panel(
            name=name,
            points=points(pts, [t.settings[name] for t in pts]),
            log_x=name in LOG_AXES and all(t.settings[name] > 0 for t in pts),
        )
    return out


def compute_curve(data: StudyData) -> ComputeCurve | Empty:
    """Each engine's best score against the side's cumulative frames simulated (every finished trial counts).

    Trials that record no frames are left out; x is the cumulative frames after each trial of the engine.
    """
    frames = 0
    with_frames: list[TrialPoint] = []
    xs: list[int] = []
    for t in data.trials:
        if t.frames is None:
            continue
        frames += t.frames
        with_frames.append(t)
        xs.append(frames)
    best = _running_best(with_frames, xs)
    if not best:
        return Empty(f"{data.name}: no scored trial records frames_simulated")
    kinds = {e: [k for k in pv.KIND_LABEL if any(t.kind == k for t in with_frames if t.engine == e)] for e in best}
    return ComputeCurve(best, kinds)


def _feature(t: TrialPoint, name: str) -> float:
    if name == "param_count":
        return float(t.param_count) if t.param_count is not None else math.nan
    if name == "n_layers":
        return float(t.n_layers) if t.n_layers is not None else math.nan
    if name == "engine":
        return 1.0 if t.engine == "v2" else 0.0
    if name == "other_agents":
        return float(t.other_agents or 0)  # v1 has none: 0 (the engine input tells the engines apart)
    return t.settings.get(name, math.nan)


def _feature_matrix(points: Sequence[TrialPoint], features: Sequence[str], standardise: bool = True) -> np.ndarray:
    rows = []
    for t in points:
        row = []
        for name in features:
            v = _feature(t, name)
            if name in LOG_AXES or name == "param_count":
                v = math.log10(v) if v > 0 else math.nan
            row.append(v)
        rows.append(row)
    x = np.asarray(rows, dtype=float).reshape(len(rows), len(features))
    if len(x):
        with np.errstate(all="ignore"):
            med = np.nanmedian(x, axis=0)
        x = np.where(np.isnan(x), np.nan_to_num(med)[None, :], x)
    if not standardise:
        return x
    std = x.std(axis=0)
    std[std == 0] = 1.0
    return (x - x.mean(axis=0)) / std


def tsne_map(studies: Sequence[StudyData], seed: int = 0, min_points: int = 5) -> TsneMap | Empty:
    """Joint t-SNE (sklearn, ``random_state=seed``) of every scored trial's settings (refinement runs left out:
    ``StudyData.settings_scored``), coloured by score.

    Features: the hyperparameters that vary across the points, plus log10 parameter count; missing
    values take the column's median (e.g. v1 rows have no other_agents).
    """
    pts = [(d.source, t) for d in studies for t in d.settings_scored]
    if len(pts) < min_points:
        return Empty(f"t-SNE needs at least {min_points} scored trials; there are {len(pts)}")
    features = [
        name
        for name in (*HYPERPARAMETERS, "param_count")
        if len({t.settings.get(name) if name != "param_count" else t.param_count for _s, t in pts}) > 1
    ]
    if not features:
        return Empty("t-SNE: every scored trial has the same settings")
    from sklearn.manifold import TSNE

    x = _feature_matrix([t for _s, t in pts], features)
    perplexity = float(min(30.0, (len(pts) - 1) / 3.0))
    emb = TSNE(n_components=2, perplexity=perplexity, random_state=seed, init="pca").fit_transform(x)
    return TsneMap(
        x=[float(v) for v in emb[:, 0]],
        y=[float(v) for v in emb[:, 1]],
        score=[float(t.value) for _s, t in pts],  # type: ignore[arg-type]
        source=[s for s, _t in pts],
        trials=[t for _s, t in pts],
        features=features,
        seed=seed,
    )


def configurations(data: StudyData) -> list[TrialPoint]:
    """The scored trials, identical settings once: the first trial of each configuration, scored with the mean
    of every trial of it (so repeats of one setting are not independent points); refinement runs left out."""
    groups: dict[str, list[TrialPoint]] = {}
    for t in data.settings_scored:  # a refinement run's score is its parent net's, trained on
        groups.setdefault(t.config_key, []).append(t)
    out = []
    for group in groups.values():
        first = group[0]
        if len(group) > 1:
            kinds = {t.kind for t in group}
            first = dataclasses.replace(
                first,
                value=float(np.mean([t.value for t in group])),
                kind=first.kind if len(kinds) == 1 else sorted(kinds, key=list(pv.KIND_LABEL).index)[0],
                label=" = ".join(t.label for t in group),
            )
        out.append(first)
    return out


def importances(
    data: StudyData, seed: int = 0, min_configs: int = 8, folds: int = 4, trees: int = 100
) -> Importances | Empty:
    """Permutation importances of a random forest predicting the score from the stored config (``FEATURES``).

    Unit: the configuration (``configurations``). The forest (sklearn, ``random_state=seed``) is fit
    on all but one of ``folds`` shuffled folds; each feature's importance is the mean drop in R² on
    the held-out fold when that feature's column is permuted (5 repeats), averaged over folds,
    clipped at 0 and normalised to sum 1. Features that never vary are left out.
    """
    units = configurations(data)
    if len(units) < min_configs:
        return Empty(f"{data.name}: importances need at least {min_configs} scored configurations, have {len(units)}")
    full = _feature_matrix(units, FEATURES, standardise=False)
    varying = [i for i in range(len(FEATURES)) if np.ptp(full[:, i]) > 0]
    if not varying:
        return Empty(f"{data.name}: no setting varies across its scored configurations")
    y = np.array([t.value for t in units], dtype=float)
    if np.ptp(y) == 0:
        return Empty(f"{data.name}: every configuration has the same score")
    from sklearn.ensemble import RandomForestRegressor
    from sklearn.model_selection import KFold

    x = full[:, varying]
    total = np.zeros(len(varying))
    rng = np.random.default_rng(seed)
    for train, test in KFold(n_splits=folds, shuffle=True, random_state=seed).split(x):
        forest = RandomForestRegressor(n_estimators=trees, min_samples_leaf=2, random_state=seed, n_jobs=1)
        forest.fit(x[train], y[train])
        total += _permutation_drop(forest, x[test], y[test], rng)
    total = np.clip(total / folds, 0.0, None)
    if total.sum() <= 0:
        return Empty(f"{data.name}: no setting predicts the score out of sample (every importance ≤ 0)")
    total /= total.sum()
    ranked = sorted(zip((FEATURES[i] for i in varying), total.tolist(), strict=True), key=lambda kv: (-kv[1], kv[0]))
    return Importances(
        names=[k for k, _ in ranked],
        values=[float(v) for _, v in ranked],
        evaluator=f"random-forest permutation importance, {folds}-fold held out (seed {seed})",
        n=len(units),
        engines=data.engines,
        kinds=data.kinds,
    )


def _r2(y: np.ndarray, pred: np.ndarray) -> np.ndarray:
    """R² of each row of ``pred`` (k × n) against ``y`` (n)."""
    ss = float(((y - y.mean()) ** 2).sum()) or 1.0
    return 1.0 - ((pred - y[None, :]) ** 2).sum(axis=1) / ss


def _permutation_drop(model: Any, x: np.ndarray, y: np.ndarray, rng: np.random.Generator, repeats: int = 5) -> Any:
    """Per feature: the mean drop in R² on (x, y) when that column is permuted (``repeats`` permutations each),
    predicted in one batch."""
    n, f = x.shape
    stacked = np.repeat(x[None, :, :], f * repeats, axis=0)
    for j in range(f):
        for r in range(repeats):
            stacked[j * repeats + r, :, j] = x[rng.permutation(n), j]
    pred = model.predict(stacked.reshape(-1, f)).reshape(f * repeats, n)
    base = _r2(y, model.predict(x)[None, :])[0]
    return (base - _r2(y, pred)).reshape(f, repeats).mean(axis=1)


def replay_comparison(replay: StudyData, crowd: StudyData) -> list[ClaimRow] | Empty:
    """Per crowd setting in a replay study: its claimed score against the mean of our seeds' official scores."""
    claims = {t.crowd_id: t for t in crowd.scored if t.crowd_id}
    runs: dict[str, list[TrialPoint]] = {}
    for t in replay.scored:
        if t.crowd_id is not None and t.crowd_id in claims:
            runs.setdefault(t.crowd_id, []).append(t)
    if not runs:
        return Empty(f"{replay.name}: no replayed crowd setting has finished with a score")
    rows = []
    for cid, trials in sorted(runs.items()):
        claim = claims[cid]
        v = [float(t.value) for t in trials]  # type: ignore[arg-type]
        rows.append(
            ClaimRow(
                crowd_id=cid,
                engine=claim.engine,
                other_agents=claim.other_agents,
                claimed=float(claim.value),  # type: ignore[arg-type]
                claim_kind=claim.kind,
                claim_confidence=claim.confidence,
                measured=float(np.mean(v)),
                measured_kind=pv.REPLAYED,
                sd=float(np.std(v, ddof=1)) if len(v) > 1 else None,
                n=len(v),
                scores=tuple(v),
            )
        )
    return rows


def own_net_rows(scores: Sequence[Any]) -> list[ClaimRow] | Empty:
    """The shipped own-weight scores (``measured.OwnNetScore``) as claimed-against-measured rows."""
    if not scores:
        return Empty("no own-weight scores shipped (python tools/crowd_measurements.py own-nets)")
    return [
        ClaimRow(
            crowd_id=s.crowd_id,
            engine=s.engine,
            other_agents=s.other_agents,
            claimed=s.claimed,
            claim_kind=s.claim_kind,
            claim_confidence=s.claim_confidence,
            measured=s.score,
            measured_kind=pv.OWN_WEIGHTS,
            sd=None,
            n=1,
            seconds=s.seconds,
            protocol=s.protocol,
        )
        for s in scores
    ]


def replay_table_rows(table: Any) -> list[ClaimRow] | Empty:
    """The shipped replay table (``measured.ReplayTable``; None = not computed) as claimed-against-replayed rows."""
    if table is None:
        from dashboards.measured import REPLAY_COMMAND

        return Empty(f"the crowd replay table has not been computed yet ({REPLAY_COMMAND})")
    rows = [
        ClaimRow(
            crowd_id=e.crowd_id,
            engine=e.engine,
            other_agents=e.other_agents,
            claimed=e.claimed,
            claim_kind=e.claim_kind,
            claim_confidence=e.claim_confidence,
            measured=e.mean,
            measured_kind=pv.REPLAYED,
            sd=e.sd,
            n=len(e.scores),
            scores=tuple(e.scores),
            seconds=e.seconds,
            protocol=e.protocol,
        )
        for e in table.entries
        if e.mean is not None
    ]
    if not rows:
        return Empty("no configuration of the crowd replay table has a complete seed")
    return rows
