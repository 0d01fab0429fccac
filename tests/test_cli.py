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
