"""The crowd sample shipped as package data: 164 public DeepTraffic submissions and 25 trained nets.

Data only (no optuna, torch or ray): ``load_submissions()`` parses and validates
``data/crowd/submissions.csv`` into typed ``Submission`` records, failing with ``CrowdDataError``
naming the row, the id and the column. A submission is its provenance, the curators' columns and
the DeepTraffic settings the file sets — ``autotune.convnet.settings.Settings``, whose columns,
types and names come from ``sim.fields`` (read by its one reader). A blank setting is kept as
``None``: the file did not set it, so deepqlearn's library default applies — ``train_config``
fills it as net.js does (``Settings.filled``).
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
from autotune.convnet.settings import Settings, read
from autotune.learner.config import TrainConfig, parse_layers
from sim import fields
from sim.config import ConfigError, FieldValueError, did_you_mean, nearest_key_error

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
    "frames_estimate",
    "net_ids",
    "net_path",
    "load_net",
]

SCORE_KINDS = ("claimed", "local", "approx", "official-example")
SCORE_CONFIDENCES = ("high", "medium", "low")
FRAMES_PER_ITERATION = 30  # train.js: totalFrames = 30·trainIterations


class CrowdDataError(ConfigError):
    """Bad crowd data: the message names the file, row (1 = first data row), id and column."""


@dataclasses.dataclass(frozen=True)
class Submission:
    """One crowd submission (one row of submissions.csv): where it comes from, the DeepTraffic settings the file
    sets (``settings``; None = blank cell, not set in the file), and what the crowd's curators read off it."""

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
    settings: Settings
    """The settings the file sets, under the columns of ``sim.fields`` (lanesSide … engine_version,
    trainer_method); its trainer method is 'sgd' etc., or None for the CSV's 'default(…)' (no tdtrainer_options)."""
    hidden_layers: str
    """Hidden layers, ``fc:<n>:<act>|svm:<n>|lrn``; '' = linear Q-function."""
    num_hidden_layers: int
    """Count of hidden layers."""
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
    notes: str | None
    """Provenance, pairing assumptions, oddities."""
    score_kind: str | None
    """claimed | local | approx | official-example (None when unscored)."""
    score_confidence: str | None
    """high | medium | low (None when unscored)."""
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

    def __getattr__(self, name: str) -> Any:
        """A setting by its field name: ``sub.other_agents`` is ``sub.settings.other_agents`` (None: not set)."""
        settings = self.__dict__.get("settings")
        if settings is None or name.startswith("_") or fields.name_of(name) != name:
            raise AttributeError(f"'Submission' object has no attribute '{name}'")
        return getattr(settings, name)

    @property
    def engine_version(self) -> str:
        """'v2' iff the file assigns otherAgents, else 'v1' (the CSV's engine_version column)."""
        return self.settings.engine

    def row(self) -> dict[str, Any]:
        """The record under the CSV's column names (dates as ISO strings; settings the file does not set: None)."""
        out = {}
        for column, name, _kind in COLUMNS:
            owner = self.settings if fields.name_of(column) is not None else self
            value = getattr(owner, name)
            out[column] = value.isoformat() if isinstance(value, dt.date) else value
        return out

    def namespace(self) -> dict[str, Any]:
        """Every value under its record name (settings by their snake_case names) and its CSV column name."""
        own = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "settings"}
        return {**own, **self.settings.values(), **self.row()}


def _column_kind(f: dataclasses.Field[Any]) -> str:
    """A column's kind from its annotation: int, float, bool, date, text (+ '?': blank allowed, None); str: blank
    is '' (the hidden layers of a linear Q-function)."""
    text = str(f.type)
    base = text.split(" | ")[0].removeprefix("dt.")
    if f.name == "hidden_layers":
        return "str"
    return {"str": "text"}.get(base, base) + ("?" if text.endswith("| None") else "")


def _setting_kind(f: fields.Field) -> str:
    """A settings column's kind: the table's type; blank allowed (not set) unless the file must set it."""
    return {int: "int", float: "float", str: "text"}[f.kind] + ("" if f.required else "?")


COLUMNS: tuple[tuple[str, str, str], ...] = (
    *((f.name, f.name, _column_kind(f)) for f in dataclasses.fields(Submission)[:6]),
    *((f.alias or f.name, f.name, _setting_kind(f)) for f in fields.FIELDS),
    *((f.name, f.name, _column_kind(f)) for f in dataclasses.fields(Submission)[7:]),
)
"""(CSV column, record field, kind): provenance, then every ``sim.fields`` setting, then the curators' columns.

Kinds: int, float, bool, date, str ('' when blank), text (+ '?' = blank allowed, None). A settings
column the file lacks is not set in any row."""
_PROVENANCE = tuple(f.name for f in dataclasses.fields(Submission) if f.name != "settings")


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
    if sub.settings.ruleset is None:
        return "engine_version", "is blank"
    if sub.score_kind is not None and sub.score_kind not in SCORE_KINDS:
        return "score_kind", f"{sub.score_kind!r} is not one of {', '.join(SCORE_KINDS)}"
    if sub.score_confidence is not None and sub.score_confidence not in SCORE_CONFIDENCES:
        return "score_confidence", f"{sub.score_confidence!r} is not one of {', '.join(SCORE_CONFIDENCES)}"
    if sub.scored and (sub.score_kind is None or sub.score_confidence is None):
        return "score_kind", "a scored row needs score_kind and score_confidence"
    if sub.reported_score_mph is not None and not 0 < sub.reported_score_mph < 100:
        return "reported_score_mph", f"{sub.reported_score_mph} mph is not a plausible DeepTraffic score"
    if (sub.settings.other_agents is None) != (sub.engine_version == "v1"):
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
    known = [c for c, _f, _k in COLUMNS]
    for column in header:
        if column not in known:
            raise CrowdDataError(f"{where}: unknown column '{column}'{did_you_mean(column, known)}")
    missing = [c for c, _f, kind in COLUMNS if c not in header and (c in _PROVENANCE or not kind.endswith("?"))]
    if missing:
        raise CrowdDataError(f"{where}: missing column(s) {', '.join(missing)}")
    out: list[Submission] = []
    seen: dict[str, int] = {}
    for number, raw in enumerate(reader, start=1):
        rid = raw.get("id") or "?"
        own: dict[str, Any] = {}
        given: dict[str, Any] = {}
        if None in raw:
            raise CrowdDataError(f"{where} row {number} (id {rid}): more cells than columns")
        for column, _name, kind in COLUMNS:
            if column not in header:
                continue
            cell = raw[column]
            if cell is None:
                raise CrowdDataError(f"{where} row {number} (id {rid}), column {column}: missing cell")
            try:
                value = _parse_cell(kind, cell)
            except ValueError as exc:
                raise CrowdDataError(f"{where} row {number} (id {rid}), column {column}: {exc}") from None
            (given if fields.name_of(column) is not None else own)[column] = value
        try:
            values, _others = read(given)
        except FieldValueError as exc:
            raise CrowdDataError(f"{where} row {number} (id {rid}), column {exc.name}: {exc.problem}") from None
        sub = Submission(**own, settings=Settings(**values))
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


def train_config(sub: Submission) -> TrainConfig:
    """The submission's ``TrainConfig``: its settings, what it leaves unset filled as the game filled it (net.js:
    deepqlearn's and the Trainer's defaults, ``Settings.filled``), and its hidden layers (none when its layer_defs
    never reached the Brain).

    Raises ``CrowdDataError`` naming the id when the settings fall outside what our learner accepts
    (e.g. momentum 5, an empty replay memory, a 4-action net); the rest of the crowd is unaffected.
    An unset trainIterations takes the template's 10,000.
    """
    layers = "" if sub.layer_defs_missing else sub.hidden_layers
    try:
        return TrainConfig.from_settings(sub.settings, nested=True, layers=parse_layers(layers))
    except ConfigError as exc:
        raise CrowdDataError(f"{sub.id}: {exc}") from None


def frames_estimate(sub: Submission) -> int | None:
    """Frames simulated to train the submission, 30·trainIterations (None when unset)."""
    iterations = sub.settings.train_iterations
    return None if iterations is None else FRAMES_PER_ITERATION * iterations


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


def load_net(submission_id: str) -> tuple[spec.ConvNet, Settings]:
    """A packaged net and its settings, cross-validated (``autotune.load_net_and_settings``)."""
    return netjson.load(net_path(submission_id))


def select(subs: Sequence[Submission], keep: Callable[[Submission], bool]) -> list[Submission]:
    """The submissions a predicate keeps, in file order."""
    return [s for s in subs if keep(s)]
