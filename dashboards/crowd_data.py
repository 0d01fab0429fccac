"""The crowd sample shipped as package data: 164 public DeepTraffic submissions and 25 trained nets.

Data only (no optuna, torch or ray): ``load_submissions()`` parses and validates
``data/crowd/submissions.csv`` into typed ``Submission`` records, failing with ``CrowdDataError``
naming the row, the id and the column. A blank hyperparameter is kept as ``None``: the file did not
set it, so deepqlearn's library default applies — ``train_config`` builds the nested (net.js-style)
mapping that makes ``TrainConfig.from_mapping`` apply exactly those defaults.
"""

from __future__ import annotations

import csv
import dataclasses
import datetime as dt
import functools
import io
import math
from collections.abc import Callable, Sequence
from importlib import resources
from pathlib import Path
from typing import Any

from autotune.convnet import netjson, spec
from autotune.learner.config import TrainConfig
from sim import fields
from sim.config import ConfigError, nearest_key_error

__all__ = [
    "CrowdDataError",
    "Submission",
    "COLUMNS",
    "SCORE_KINDS",
    "SCORE_CONFIDENCES",
    "data_dir",
    "load_submissions",
    "parse_submissions",
    "train_config",
    "param_count",
    "frames_estimate",
    "net_ids",
    "net_path",
    "load_net",
]

SCORE_KINDS = ("claimed", "local", "approx", "official-example")
SCORE_CONFIDENCES = ("high", "medium", "low")
ENGINES = ("v1", "v2")
FRAMES_PER_ITERATION = 30  # train.js: totalFrames = 30·trainIterations


class CrowdDataError(ConfigError):
    """Bad crowd data: the message names the file, row (1 = first data row), id and column."""


@dataclasses.dataclass(frozen=True)
class Submission:
    """One crowd submission (one row of submissions.csv); ``None`` = blank cell (not set in the file)."""

    id: str
    """``dt-<owner>--<repo>-vNN``: unique row id."""
    repo: str
    """GitHub owner/name the version lives in."""
    path: str
    """File path inside the repository."""
    commit: str
    """Commit that last changed this file version."""
    version_date: dt.date | None
    """Author date of that commit (None for the rows read without a snapshot)."""
    version_index: int
    """Chronological order of this version within its repository."""
    lanes_side: int
    """lanesSide [lanes] (column lanesSide)."""
    patches_ahead: int
    """patchesAhead [rows] (column patchesAhead)."""
    patches_behind: int
    """patchesBehind [rows] (column patchesBehind)."""
    train_iterations: int | None
    """trainIterations [decisions] (column trainIterations)."""
    other_agents: int | None
    """otherAgents [cars] (column otherAgents); None in v1-engine files."""
    temporal_window: int | None
    """deepqlearn temporal_window (None: library default 1)."""
    hidden_layers: str
    """Hidden layers, ``fc:<n>:<act>|svm:<n>|lrn``; '' = linear Q-function."""
    num_hidden_layers: int
    """Count of hidden layers."""
    learning_rate: float | None
    """Trainer learning rate (None: Trainer default 0.01)."""
    momentum: float | None
    """Trainer momentum (None: Trainer default 0.9 when options were given)."""
    batch_size: int | None
    """Trainer batch size."""
    l2_decay: float | None
    """Trainer L2 decay (None: Trainer default 0)."""
    l1_decay: float | None
    """Trainer L1 decay (None: 0)."""
    gamma: float | None
    """Discount γ (None: deepqlearn default 0.8)."""
    experience_size: int | None
    """Replay memory size (None: 30000)."""
    start_learn_threshold: int | None
    """Learning start threshold (None: ⌊min(0.1·experience, 1000)⌋)."""
    learning_steps_total: int | None
    """Age at which ε reaches ε_min (None: 100000)."""
    learning_steps_burnin: int | None
    """Age until which ε = 1 (None: 3000)."""
    epsilon_min: float | None
    """Exploration floor (None: 0.05)."""
    epsilon_test_time: float | None
    """Exploration at test time (None: 0.01)."""
    num_inputs_formula_ok: bool
    """num_inputs, num_actions and input size agree with the formulas."""
    n_params: int
    """Weights + biases of the MLP as the crowd README counts them."""
    has_weights: bool
    """The file appends trained weights (``value_net.fromJSON``)."""
    reported_score_mph: float | None
    """Self-reported score [mph]; None = no score stated."""
    score_source: str | None
    """Where the score is stated (short quote)."""
    engine_version: str
    """'v2' iff the file assigns otherAgents, else 'v1'."""
    notes: str | None
    """Provenance, pairing assumptions, oddities."""
    score_kind: str | None
    """claimed | local | approx | official-example (None when unscored)."""
    score_confidence: str | None
    """high | medium | low (None when unscored)."""
    trainer_method: str
    """tdtrainer method; 'default(...)' = no tdtrainer_options in the file."""
    weights_match_config: bool | None
    """Appended weights have the structure the config builds (None: no weights)."""
    weights_structure: str | None
    """Structure read from the weights, e.g. ``in420:36:tanh|24:tanh|5``."""
    same_config_as: str | None
    """Id of an earlier row with the same config (independent score or weights)."""
    is_default_template: bool
    """The page's unmodified default template."""
    layer_defs_missing: bool
    """opt.layer_defs never reached the Brain, so deepqlearn's default linear net was trained."""
    config_hash: str
    """Hash of the configuration (stricter dedup)."""
    weights_sha1_12: str | None
    """First 12 hex digits of the weights' SHA-1."""
    num_inputs_declared: int
    """num_inputs as the file declared it."""
    input_layer_size: int | None
    """Input layer size of layer_defs."""
    net_inputs_std: int
    """num_inputs·tw + 5·tw + num_inputs."""
    manual_transcription: bool
    """Values typed from text instead of executing the file."""
    in_nets_dir: bool
    """Weights saved under nets/."""

    @property
    def scored(self) -> bool:
        """Whether the submission states a score."""
        return self.reported_score_mph is not None

    def row(self) -> dict[str, Any]:
        """The record under the CSV's column names (dates as ISO strings)."""
        out = {}
        for column, field, _kind in COLUMNS:
            value = getattr(self, field)
            out[column] = value.isoformat() if isinstance(value, dt.date) else value
        return out


# CSV column -> (record field, kind); kinds end in '?' when a blank cell is allowed (-> None).
_KINDS: dict[str, tuple[str, str]] = {
    "lanesSide": ("lanes_side", "int"),
    "patchesAhead": ("patches_ahead", "int"),
    "patchesBehind": ("patches_behind", "int"),
    "trainIterations": ("train_iterations", "int?"),
    "otherAgents": ("other_agents", "int?"),
    "version_date": ("version_date", "date?"),
    "version_index": ("version_index", "int"),
    "temporal_window": ("temporal_window", "int?"),
    "hidden_layers": ("hidden_layers", "str?"),
    "num_hidden_layers": ("num_hidden_layers", "int"),
    "learning_rate": ("learning_rate", "float?"),
    "momentum": ("momentum", "float?"),
    "batch_size": ("batch_size", "int?"),
    "l2_decay": ("l2_decay", "float?"),
    "l1_decay": ("l1_decay", "float?"),
    "gamma": ("gamma", "float?"),
    "experience_size": ("experience_size", "int?"),
    "start_learn_threshold": ("start_learn_threshold", "int?"),
    "learning_steps_total": ("learning_steps_total", "int?"),
    "learning_steps_burnin": ("learning_steps_burnin", "int?"),
    "epsilon_min": ("epsilon_min", "float?"),
    "epsilon_test_time": ("epsilon_test_time", "float?"),
    "num_inputs_formula_ok": ("num_inputs_formula_ok", "bool"),
    "n_params": ("n_params", "int"),
    "has_weights": ("has_weights", "bool"),
    "reported_score_mph": ("reported_score_mph", "float?"),
    "score_source": ("score_source", "text?"),
    "notes": ("notes", "text?"),
    "score_kind": ("score_kind", "text?"),
    "score_confidence": ("score_confidence", "text?"),
    "weights_match_config": ("weights_match_config", "bool?"),
    "weights_structure": ("weights_structure", "text?"),
    "same_config_as": ("same_config_as", "text?"),
    "is_default_template": ("is_default_template", "bool"),
    "layer_defs_missing": ("layer_defs_missing", "bool"),
    "weights_sha1_12": ("weights_sha1_12", "text?"),
    "num_inputs_declared": ("num_inputs_declared", "int"),
    "input_layer_size": ("input_layer_size", "int?"),
    "net_inputs_std": ("net_inputs_std", "int"),
    "manual_transcription": ("manual_transcription", "bool"),
    "in_nets_dir": ("in_nets_dir", "bool"),
}
_ORDER = (
    "id,repo,path,commit,version_date,version_index,lanesSide,patchesAhead,patchesBehind,trainIterations,otherAgents,"
    "temporal_window,hidden_layers,num_hidden_layers,learning_rate,momentum,batch_size,l2_decay,l1_decay,gamma,"
    "experience_size,start_learn_threshold,learning_steps_total,learning_steps_burnin,epsilon_min,epsilon_test_time,"
    "num_inputs_formula_ok,n_params,has_weights,reported_score_mph,score_source,engine_version,notes,score_kind,"
    "score_confidence,trainer_method,weights_match_config,weights_structure,same_config_as,is_default_template,"
    "layer_defs_missing,config_hash,weights_sha1_12,num_inputs_declared,input_layer_size,net_inputs_std,"
    "manual_transcription,in_nets_dir"
).split(",")
COLUMNS: tuple[tuple[str, str, str], ...] = tuple((c, *_KINDS.get(c, (c, "text"))) for c in _ORDER)
"""(CSV column, record field, kind) in file order; kinds: int, float, bool, date, str, text (+ '?' = blank allowed)."""


def data_dir() -> Path:
    """Directory of the packaged crowd data (submissions.csv, nets/)."""
    return Path(str(resources.files("dashboards") / "data" / "crowd"))


def _parse_cell(kind: str, text: str) -> Any:
    optional = kind.endswith("?")
    base = kind.rstrip("?")
    if text == "":
        if optional or base == "str":
            return None if base != "str" else ""
        raise ValueError("is blank")
    if base in ("str", "text"):
        return text
    if base == "bool":
        if text not in ("true", "false"):
            raise ValueError(f"{text!r} is not true/false")
        return text == "true"
    if base == "date":
        try:
            return dt.date.fromisoformat(text)
        except ValueError:
            raise ValueError(f"{text!r} is not a YYYY-MM-DD date") from None
    try:
        number = float(text)
    except ValueError:
        raise ValueError(f"{text!r} is not a number") from None
    if not math.isfinite(number):
        raise ValueError(f"{text!r} is not a finite number")
    if base == "int":
        if not number.is_integer():
            raise ValueError(f"{text!r} is not an integer")
        return int(number)
    return number


def _check_row(sub: Submission) -> tuple[str, str] | None:
    """(column, problem) of the first semantic inconsistency in a parsed row, else None."""
    if sub.engine_version not in ENGINES:
        return "engine_version", f"{sub.engine_version!r} is not one of {', '.join(ENGINES)}"
    if sub.score_kind is not None and sub.score_kind not in SCORE_KINDS:
        return "score_kind", f"{sub.score_kind!r} is not one of {', '.join(SCORE_KINDS)}"
    if sub.score_confidence is not None and sub.score_confidence not in SCORE_CONFIDENCES:
        return "score_confidence", f"{sub.score_confidence!r} is not one of {', '.join(SCORE_CONFIDENCES)}"
    if sub.scored and (sub.score_kind is None or sub.score_confidence is None):
        return "score_kind", "a scored row needs score_kind and score_confidence"
    if sub.reported_score_mph is not None and not 0 < sub.reported_score_mph < 100:
        return "reported_score_mph", f"{sub.reported_score_mph} mph is not a plausible DeepTraffic score"
    if (sub.other_agents is None) != (sub.engine_version == "v1"):
        return "otherAgents", "must be blank exactly for v1-engine rows"
    hidden = [p for p in sub.hidden_layers.split("|") if p] if sub.hidden_layers else []
    if len(hidden) != sub.num_hidden_layers:
        return "num_hidden_layers", f"{sub.num_hidden_layers} ≠ {len(hidden)} layers in hidden_layers"
    if not sub.id.endswith(f"-v{sub.version_index:02d}"):
        return "id", f"{sub.id!r} does not end in -v{sub.version_index:02d} (version_index)"
    return None


def parse_submissions(text: str, where: str = "submissions.csv") -> tuple[Submission, ...]:
    """Parse and validate submissions CSV text; ``CrowdDataError`` names the row, id and column."""
    reader = csv.DictReader(io.StringIO(text))
    header = list(reader.fieldnames or [])
    for column in header:
        if column not in _ORDER:
            try:
                raise nearest_key_error(f"{where}: column", column, _ORDER)
            except ConfigError as exc:
                raise CrowdDataError(str(exc)) from None
    missing = [c for c in _ORDER if c not in header]
    if missing:
        raise CrowdDataError(f"{where}: missing column(s) {', '.join(missing)}")
    out: list[Submission] = []
    seen: dict[str, int] = {}
    for number, raw in enumerate(reader, start=1):
        rid = raw.get("id") or "?"
        values: dict[str, Any] = {}
        if None in raw:
            raise CrowdDataError(f"{where} row {number} (id {rid}): more cells than columns")
        for column, field, kind in COLUMNS:
            cell = raw[column]
            if cell is None:
                raise CrowdDataError(f"{where} row {number} (id {rid}), column {column}: missing cell")
            try:
                values[field] = _parse_cell(kind, cell)
            except ValueError as exc:
                raise CrowdDataError(f"{where} row {number} (id {rid}), column {column}: {exc}") from None
        sub = Submission(**values)
        problem = _check_row(sub)
        if problem is not None:
            raise CrowdDataError(f"{where} row {number} (id {rid}), column {problem[0]}: {problem[1]}")
        if sub.id in seen:
            raise CrowdDataError(f"{where} row {number}, column id: {sub.id!r} repeats row {seen[sub.id]}")
        seen[sub.id] = number
        out.append(sub)
    return tuple(out)


@functools.lru_cache(maxsize=1)
def load_submissions() -> tuple[Submission, ...]:
    """The 164 packaged submissions, validated (cached: the data is immutable)."""
    path = data_dir() / "submissions.csv"
    return parse_submissions(path.read_text(encoding="utf-8"), where=str(path.name))


def _trainer_options(sub: Submission) -> dict[str, Any] | None:
    if sub.trainer_method.startswith("default"):
        return None  # no tdtrainer_options in the file: the Brain's own trainer options apply
    options: dict[str, Any] = {"method": sub.trainer_method}
    for key in fields.TRAINER_NAMES:
        value = getattr(sub, key)
        if value is not None:
            options[key] = value
    return options


def config_mapping(sub: Submission) -> dict[str, Any]:
    """The nested (net.js-style) mapping of a submission: only what the file set, so blanks take library defaults."""
    out: dict[str, Any] = {
        "ruleset": sub.engine_version,
        "lanesSide": sub.lanes_side,
        "patchesAhead": sub.patches_ahead,
        "patchesBehind": sub.patches_behind,
        "hidden_layers": "" if sub.layer_defs_missing else sub.hidden_layers,
    }
    if sub.train_iterations is not None:
        out["trainIterations"] = sub.train_iterations
    if sub.other_agents is not None:
        out["otherAgents"] = sub.other_agents
    opt: dict[str, Any] = {}
    for key in fields.OPT_NAMES:
        value = getattr(sub, key)
        if value is not None:
            opt[key] = value
    trainer = _trainer_options(sub)
    if trainer is not None:
        opt["tdtrainer_options"] = trainer
    out["opt"] = opt
    return out


def train_config(sub: Submission) -> TrainConfig:
    """The submission's ``TrainConfig`` (blanks → deepqlearn / convnetjs defaults, as the game applied them).

    Raises ``CrowdDataError`` naming the id when the settings fall outside what our learner accepts
    (e.g. momentum 5, an empty replay memory, a 4-action net); the rest of the crowd is unaffected.
    An unset trainIterations takes the template's 10,000.
    """
    try:
        return TrainConfig.from_mapping(config_mapping(sub))
    except ConfigError as exc:
        raise CrowdDataError(f"{sub.id}: {exc}") from None


def param_count(config: TrainConfig) -> int:
    """Weights + biases of the net the config builds (fc layers; maxout/svm/lrn add none)."""
    sizes = spec.layer_sizes(config.expanded_layers)
    return sum(
        (n_in + 1) * n_out
        for layer, (n_in, n_out) in zip(config.expanded_layers, sizes, strict=True)
        if isinstance(layer, spec.FC)
    )


def frames_estimate(sub: Submission) -> int | None:
    """Frames simulated to train the submission, 30·trainIterations (None when unset)."""
    return None if sub.train_iterations is None else FRAMES_PER_ITERATION * sub.train_iterations


def net_ids() -> tuple[str, ...]:
    """Ids of the 25 packaged trained nets, sorted."""
    names = sorted(p.name for p in (data_dir() / "nets").glob("*.config.json"))
    return tuple(n[: -len(".config.json")] for n in names)


def net_path(submission_id: str) -> Path:
    """Path of a packaged net's JSON (its ``.config.json`` lies beside it)."""
    path = data_dir() / "nets" / f"{submission_id}.json"
    if not path.exists():
        raise nearest_key_error("crowd net", submission_id, list(net_ids()))
    return path


def load_net(submission_id: str) -> tuple[spec.ConvNet, netjson.NetSettings]:
    """A packaged net and its settings, cross-validated (``autotune.load_net_and_settings``)."""
    return netjson.load(net_path(submission_id))


def select(subs: Sequence[Submission], keep: Callable[[Submission], bool]) -> list[Submission]:
    """The submissions a predicate keeps, in file order."""
    return [s for s in subs if keep(s)]
