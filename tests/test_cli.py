"""``autotune <subcommand>``: the table of subcommands, ``--help`` everywhere, one-line errors with exit 2."""

from __future__ import annotations

import argparse
import importlib
import subprocess
import sys

import pytest

from autotune import cli
from tests.conftest import ROOT


def _subcommand_names() -> list[str]:
    """Every registered subcommand (a module may add several)."""
    parser = cli.build_parser()
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return list(action.choices)


NAMES = _subcommand_names()


def test_every_subcommand_module_has_the_interface() -> None:
    for module_name in cli.SUBCOMMANDS:
        module = importlib.import_module(module_name)
        assert callable(module.add_parser) and callable(module.run), module_name
    assert {"train", "evaluate"} <= set(NAMES)


@pytest.mark.parametrize("argv", [["--help"], *[[name, "--help"] for name in NAMES]])
def test_help_exits_0(argv: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(argv) == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: autotune") and "--help" in out


@pytest.mark.parametrize(
    "argv, needle",
    [
        ([], "required: <command>"),
        (["nope"], "invalid choice: 'nope'"),
        (["train", "--out", "o", "--bogus"], "unrecognized arguments: --bogus"),
    ],
)
def test_bad_arguments_one_line_exit_2(argv: list[str], needle: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: ") and needle in err


def test_python_m_shims_are_the_cli() -> None:
    for name in ("train", "evaluate"):
        proc = subprocess.run(
            [sys.executable, "-m", f"autotune.{name}", "--help"], cwd=ROOT, capture_output=True, text=True, timeout=120
        )
        assert proc.returncode == 0 and proc.stdout.startswith(f"usage: autotune {name}"), proc.stderr


def test_configure_process_sets_the_process_once() -> None:
    """In a fresh process (it changes process-wide state): threads and denormal flushing stay set."""
    code = (
        "import torch, autotune\n"
        "from autotune.runtime import process_configured\n"
        "assert not process_configured()\n"
        "autotune.configure_process(1)\n"
        "assert process_configured() and torch.get_num_threads() == 1\n"
        "assert torch.tensor([1e-40]).item() == 0.0  # float32 denormal flushed\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr


def _error_types() -> list[type]:
    from autotune.convnet.netjson import NetFormatError
    from autotune.convnet.spec import NetSpecError
    from autotune.search.records import RecordError
    from autotune.search.spec import SpecError
    from autotune.search.storage import StorageError, UnknownStudyError
    from dashboards.crowd_data import CrowdDataError
    from dashboards.crowd_filter import FilterError
    from sim.config import ConfigError

    return [ConfigError, NetFormatError, NetSpecError, SpecError, StorageError, UnknownStudyError, RecordError,
            CrowdDataError, FilterError]  # fmt: skip


@pytest.mark.parametrize("error", _error_types(), ids=lambda e: e.__name__)
def test_every_bad_input_error_is_one_line_exit_2_in_main(
    error: type, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Net, spec, storage, record, crowd and filter errors are ConfigErrors; ``main`` alone prints them."""
    from sim.config import ConfigError

    assert issubclass(error, ConfigError)

    def run(args: argparse.Namespace) -> int:
        raise error("--out: the problem; the fix\nmore detail that a terminal line does not need")

    monkeypatch.setattr("autotune.commands.replay.run", run)
    assert cli.main(["replay", "--out", "x.gif"]) == 2
    assert capsys.readouterr().err == "error: --out: the problem; the fix\n"


def test_commands_live_in_autotune_commands() -> None:
    """One roof: every subcommand module is ``autotune.commands.<name>``, and none catches ConfigError itself."""
    import ast

    assert all(m.startswith("autotune.commands.") for m in cli.SUBCOMMANDS)
    for module_name in cli.SUBCOMMANDS:
        path = ROOT / (module_name.replace(".", "/") + ".py")
        caught = [
            ast.unparse(handler.type)
            for handler in ast.walk(ast.parse(path.read_text()))
            if isinstance(handler, ast.ExceptHandler) and handler.type is not None
        ]
        assert not [c for c in caught if "ConfigError" in c or c == "ValueError"], (module_name, caught)
