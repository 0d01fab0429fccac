"""Study specs: the shipped configs load, and every bad input is ONE line naming file, table, key and fix."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from autotune.search import space
from autotune.search.spec import FRACTIONS, PARAMS, SpecError, StudySpec, load_spec, parse_spec
from sim.config import ConfigError
from tests.conftest import ROOT

CONFIGS = ROOT / "study_configs"
SHIPPED = ("smoke.toml", "quick.toml", "paper.toml")

# the paper's Table 1 (the hyperparameters the crowd tuned; gamma as one_minus_gamma) and the layout
TABLE1 = (
    "lanes_side", "patches_ahead", "patches_behind", "other_agents", "train_iterations", "temporal_window",
    "experience_size", "start_learn_threshold", "one_minus_gamma", "learning_steps_total", "learning_steps_burnin",
    "epsilon_min", "epsilon_test_time", "learning_rate", "momentum", "batch_size", "l2_decay",
    "n_layers", "neurons", "activation",
)  # fmt: skip

MINIMAL = """
[study]
name = "t"
n_trials = 3
"""


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "x.toml"
    path.write_text(text)
    return path


def _error(tmp_path: Path, text: str) -> str:
    path = _write(tmp_path, text)
    with pytest.raises(SpecError) as info:
        space.check(load_spec(path))  # as `autotune launch` validates a spec: its tables, then its space's corners
    msg = str(info.value)
    assert "\n" not in msg, msg
    assert msg.startswith(f"{path}: "), msg
    return msg


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_configs_load(name: str) -> None:
    spec = space.check(load_spec(CONFIGS / name))
    assert spec.study.name == Path(name).stem
    assert spec.evaluation.final_protocol == "v2-official"
    assert spec.study.n_trials is not None or spec.study.timeout_s is not None
    again = parse_spec(json.loads(json.dumps(spec.to_dict())), source=spec.source)
    assert again == spec


def test_paper_toml_is_the_paper_space() -> None:
    spec = load_spec(CONFIGS / "paper.toml")
    paper = parse_spec({"study": {"name": "d", "n_trials": 1}, "ladder": {"rungs": list(spec.ladder)},
                        "space": space.PAPER_SPACE})  # fmt: skip
    assert spec.space == paper.space
    assert spec.fixed == ()
    # every Table-1 setting but the ladder's (training length, ε's schedule as fractions of it), and the trainer method
    ladder = {"train_iterations", "learning_steps_total", "learning_steps_burnin"}
    # and the learning rate per input of the net; ε_test is chosen per trained net from the ladder's grid
    assert spec.ladder_epsilon_grid == (0.0, 0.05, 0.2, 0.45, 0.7)
    assert {d.name for d in spec.space} == (set(TABLE1) - ladder - {"learning_rate", "epsilon_test_time"}) | set(
        FRACTIONS
    ) | {
        "method",
        "learning_rate_x_inputs",
    }
    assert set(TABLE1) <= set(PARAMS)
    assert spec.ladder == (10_000, 30_000, 90_000, 270_000, 810_000) and spec.study.pruner == "sha"
    assert spec.ladder_min_top == 90_000 and spec.gated_rungs == 3  # every sampled draw affords 90k
    classic = parse_spec({"study": {"name": "d", "n_trials": 1}, "space": space.DEFAULT_SPACE})
    assert not classic.ladder and {d.name for d in classic.space} == set(TABLE1)  # the crowd study's space


def test_defaults(tmp_path: Path) -> None:
    spec = load_spec(_write(tmp_path, MINIMAL))
    assert (spec.study.sampler, spec.study.pruner, spec.study.seed, spec.study.storage) == ("tpe", "median", 0, "")
    assert spec.study.max_retries == 2 and spec.study.trial_timeout_s > 0
    assert spec.evaluation.report_points == 10 and spec.evaluation.final_protocol == "v2-official"
    assert spec.resources.workers >= 1
    v1 = load_spec(_write(tmp_path, MINIMAL.replace('name = "t"', 'name = "t"\nruleset = "v1"')))
    assert v1.evaluation.final_protocol == "v1-original"
    unnamed = load_spec(_write(tmp_path, "[study]\nn_trials = 1\n"))
    assert unnamed.study.name == "x"  # the file's stem


def test_fixed_normalised(tmp_path: Path) -> None:
    spec = load_spec(_write(tmp_path, MINIMAL + '[fixed]\notherAgents = 10\nlayers = "fc:384:tanh"\ngamma = 1\n'))
    assert spec.fixed_values == {"other_agents": 10, "layers": "fc:384:tanh", "gamma": 1.0}
    config = space.to_config(spec, {})
    assert config.other_agents == 10 and config.hidden == "fc:384:tanh"


def test_overrides(tmp_path: Path) -> None:
    spec = load_spec(_write(tmp_path, MINIMAL))
    new = spec.with_overrides(storage="postgresql://u@h/db", name="other", workers=3, n_trials=7, timeout_s=60)
    assert (new.study.storage, new.study.name, new.resources.workers) == ("postgresql://u@h/db", "other", 3)
    assert (new.study.n_trials, new.study.timeout_s) == (7, 60.0)
    assert spec.with_overrides() == spec
    for kwargs, flag in (
        ({"workers": 0}, "--workers"),
        ({"n_trials": -1}, "--n-trials"),
        ({"timeout_s": 0}, "--timeout"),
        ({"name": "a b/c"}, "--study-name"),
    ):
        with pytest.raises(SpecError, match=flag) as info:
            spec.with_overrides(**kwargs)  # type: ignore[arg-type]
        assert "\n" not in str(info.value)


def test_spec_error_is_a_config_error() -> None:
    assert issubclass(SpecError, ConfigError) and issubclass(SpecError, ValueError)


BAD: list[tuple[str, str, tuple[str, ...]]] = [
    # (what, TOML appended to MINIMAL or a whole file, fragments the message must contain)
    ("low > high", "[space]\nlearning_rate = { low = 0.1, high = 0.01 }\n",
     ("[space] learning_rate:", "low 0.1 > high 0.01", "swap them")),
    ("unknown study key", "[study]\nsamplr = 'tpe'\nname = 't'\nn_trials = 1\n",
     ("[study] samplr: unknown key", "did you mean 'sampler'?")),
    ("unknown sampler", MINIMAL.replace("n_trials = 3", "n_trials = 3\nsampler = 'tpee'"),
     ("[study] sampler:", "'tpee'", "tpe, cmaes, gp, random, qmc")),
    ("unknown pruner", MINIMAL.replace("n_trials = 3", "n_trials = 3\npruner = 'medain'"),
     ("[study] pruner:", "did you mean 'median'?", "median, hyperband, sha, wilcoxon, none")),
    ("unknown table", MINIMAL + "[spaec]\n", ("[spaec]: unknown table", "did you mean 'space'?")),
    ("key outside any table", "sampler = 'tpe'\n" + MINIMAL, ("sampler:", "move it under [study]")),
    ("fixed key outside any table", "lanesSide = 2\n" + MINIMAL, ("lanesSide:", "move it under [fixed]")),
    ("unknown param", "[space]\nlanes_sid = { low = 0, high = 3 }\n",
     ("[space] lanes_sid: unknown parameter", "did you mean 'lanes_side'?")),
    ("unknown fixed key", "[fixed]\nlaneSide = 3\n", ("[fixed] laneSide: unknown key", "did you mean 'lanesSide'?")),
    ("fixed out of range", "[fixed]\nlanesSide = 60\n", ("[fixed] lanes_side:", "60", "0–50")),
    ("fixed bad type", "[fixed]\ngamma = 'high'\n", ("[fixed] gamma:",)),
    ("fixed bad layers", "[fixed]\nlayers = 'fc:10:tanhh'\n", ("[fixed] layers", "did you mean 'tanh'?")),
    ("fixed start >= experience", "[fixed]\nexperience_size = 100\nstart_learn_threshold = 100\n",
     ("[fixed] start_learn_threshold:", "experience_size 100")),
    ("fixed ruleset", "[fixed]\nruleset = 'v1'\n", ("[fixed] ruleset:", "[study] ruleset")),
    ("fixed ruleset by its alias", "[fixed]\nengine_version = 'v1'\n", ("[fixed] engine_version:", "[study] ruleset")),
    ("unknown ruleset", MINIMAL.replace("n_trials = 3", "n_trials = 3\nruleset = 'v3'"),
     ("[study] ruleset:", "'v3' is not allowed", "use one of v1, v2")),
    ("unknown trainer method", "[space]\nmethod = { choices = ['sgd', 'adagrd'] }\n",
     ("[space] method:", "choice 'adagrd' is not allowed", "did you mean 'adagrad'?")),
    ("fixed unknown trainer method", "[fixed]\nmethod = 'adam'\n", ("[fixed] method:", "did you mean 'adagrad'?")),
    ("v1 with agents", MINIMAL.replace("n_trials = 3", "n_trials = 3\nruleset = 'v1'") + "[fixed]\notherAgents = 3\n",
     ("[fixed] other_agents:", "v1")),
    ("v1 searching agents", MINIMAL.replace("n_trials = 3", "n_trials = 3\nruleset = 'v1'")
     + "[space]\nother_agents = { low = 0, high = 3 }\n", ("[space] other_agents:", "v1")),
    ("bound above the site's", "[space]\nlanes_side = { low = 0, high = 60 }\n",
     ("[space] lanes_side:", "high 60 is above what deepqlearn accepts (0–50)", "lower it to 50")),
    ("bound below the site's", "[space]\nbatch_size = { low = 0, high = 64 }\n",
     ("[space] batch_size:", "low 0 is below", "raise it to 1")),
    ("gamma bound", "[space]\none_minus_gamma = { low = 0.1, high = 1.5 }\n", ("[space] one_minus_gamma:", "high 1.5")),
    ("log with low 0", "[space]\nmomentum = { low = 0.0, high = 0.9, log = true }\n",
     ("[space] momentum:", "log scale needs low > 0")),
    ("step with log", "[space]\nlearning_rate = { low = 0.001, high = 0.01, log = true, step = 0.001 }\n",
     ("[space] learning_rate:", "step and log")),
    ("step not dividing", "[space]\nmomentum = { low = 0.0, high = 0.95, step = 0.1 }\n",
     ("[space] momentum:", "not a multiple of step", "set high = 0.9")),
    ("int bound not integer", "[space]\nlanes_side = { low = 0, high = 2.5 }\n",
     ("[space] lanes_side:", "high 2.5 is not an integer")),
    ("empty choices", "[space]\nbatch_size = { choices = [] }\n", ("[space] batch_size:", "non-empty")),
    ("invalid choice", "[space]\nbatch_size = { choices = [32, 5000] }\n", ("[space] batch_size:", "choice 5000")),
    ("bad activation", "[space]\nn_layers = { low = 1, high = 2 }\nneurons = { low = 4, high = 8 }\n"
     "activation = { choices = ['relu', 'tanhh'] }\n", ("[space] activation:", "'tanhh'", "did you mean 'tanh'?")),
    ("activation range", "[space]\nactivation = { low = 1, high = 2 }\n", ("[space] activation:", "needs choices")),
    ("range and choices", "[space]\nbatch_size = { low = 1, high = 2, choices = [1] }\n",
     ("[space] batch_size:", "choices and low")),
    ("missing high", "[space]\nbatch_size = { low = 1 }\n", ("[space] batch_size:", "high is missing")),
    ("entry key typo", "[space]\nbatch_size = { low = 1, hihg = 2 }\n",
     ("[space] batch_size.hihg: unknown key", "did you mean 'high'?")),
    ("a value instead of a range", "[space]\nbatch_size = 32\n", ("[space] batch_size:", "put batch_size in [fixed]")),
    ("low = high", "[space]\nbatch_size = { low = 32, high = 32 }\n", ("[space] batch_size:", "searches nothing")),
    ("fixed key typo", "[fixed]\nbatchsize = 3\n", ("[fixed] batchsize: unknown key", "did you mean 'batch_size'?")),
    ("both fixed and searched", "[fixed]\nbatch_size = 32\n[space]\nbatch_size = { low = 16, high = 64 }\n",
     ("[space] batch_size:", "[fixed] also sets batch_size")),
    ("gamma fixed and searched", "[fixed]\ngamma = 0.9\n[space]\none_minus_gamma = { low = 0.01, high = 0.1 }\n",
     ("[space] one_minus_gamma:", "[fixed] also sets gamma")),
    ("layers fixed and searched", "[fixed]\nlayers = 'fc:8:relu'\n[space]\nn_layers = { low = 1, high = 2 }\n"
     "neurons = { low = 4, high = 8 }\nactivation = { choices = ['relu'] }\n",
     ("[space] n_layers:", "also sets layers")),
    ("incomplete layout", "[space]\nn_layers = { low = 1, high = 2 }\nactivation = { choices = ['relu'] }\n",
     ("[space] neurons: missing", "add neurons =")),
    ("gamma searched directly", "[space]\ngamma = { low = 0.5, high = 0.9 }\n", ("[space] gamma:", "one_minus_gamma")),
    ("maxout with 1 neuron", "[space]\nn_layers = { low = 1, high = 2 }\nneurons = { low = 1, high = 8 }\n"
     "activation = { choices = ['relu', 'maxout'] }\n", ("[space] neurons 1 with activation 'maxout'", "narrow")),
    ("empty input at the low corner",
     "[space]\npatches_ahead = { low = 0, high = 3 }\npatches_behind = { low = 0, high = 3 }\n",
     ("[space] the low corner", "patches_ahead + patches_behind")),
    ("fixed start vs searched experience", "[fixed]\nstart_learn_threshold = 5000\n"
     "[space]\nexperience_size = { low = 1000, high = 100000, log = true }\n",
     ("[space] experience_size:", "start_learn_threshold 5000", "raise experience_size.low above 5000")),
    ("wrong final protocol", "[evaluation]\nfinal_protocol = 'v1-original'\n",
     ("[evaluation] final_protocol:", "use 'v2-official'")),
    ("warmup too long", "[evaluation]\nreport_points = 3\nn_warmup_steps = 3\n",
     ("[evaluation] n_warmup_steps:", "use 0–2")),
    ("unknown evaluation key", "[evaluation]\nquick_run = 3\n",
     ("[evaluation] quick_run: unknown key", "did you mean 'quick_runs'?")),
    ("bad workers", "[resources]\nworkers = 0\n", ("[resources] workers:",)),
    ("unknown resources key", "[resources]\ngpu_per_trial = 1\n", ("[resources] gpu_per_trial", "'gpus_per_trial'")),
    ("no budget", "[study]\nname = 't'\n", ("[study] n_trials:", "never end")),
    ("bad name", "[study]\nname = 'a b'\nn_trials = 1\n", ("[study] name:", "not a usable study name")),
    ("negative seed", MINIMAL.replace("n_trials = 3", "n_trials = 3\nseed = -1"), ("[study] seed:", "out of range")),
    ("malformed TOML", MINIMAL + "[space]\nlearning_rate = { low = 0.1 high = 1 }\n",
     ("[space] (line 6, column", "invalid TOML", "fix the syntax")),
]  # fmt: skip


@pytest.mark.parametrize(("what", "text", "fragments"), BAD, ids=[b[0] for b in BAD])
def test_bad_input_one_line(tmp_path: Path, what: str, text: str, fragments: tuple[str, ...]) -> None:
    if "[study]" not in text:
        text = MINIMAL + text
    msg = _error(tmp_path, text)
    for fragment in fragments:
        assert fragment in msg, f"{what}: {fragment!r} not in {msg!r}"


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(SpecError, match="x.toml: file not found"):
        load_spec(tmp_path / "x.toml")


def test_spec_is_frozen_and_hashable(tmp_path: Path) -> None:
    spec = load_spec(CONFIGS / "quick.toml")
    with pytest.raises(AttributeError):
        spec.study = spec.study  # type: ignore[misc]
    assert hash(spec) == hash(load_spec(CONFIGS / "quick.toml"))
    assert isinstance(spec, StudySpec)


def test_trainer_method_is_searchable() -> None:
    """The table's categorical settings are [space] parameters like any other (choices from sim.fields)."""
    spec = parse_spec(
        {
            "study": {"name": "m", "n_trials": 1},
            "space": {"method": {"choices": ["sgd", "adadelta"]}, "ro": {"low": 0.5, "high": 0.99}},
        }
    )
    config = space.to_config(spec, {"method": "adadelta", "ro": 0.9})
    assert (config.method, config.ro) == ("adadelta", 0.9)
    assert space.encode(spec, config) == {"method": "adadelta", "ro": 0.9}
    assert config.to_deepqlearn()["opt"]["tdtrainer_options"]["method"] == "adadelta"
