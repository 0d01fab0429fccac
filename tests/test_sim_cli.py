"""``python -m sim.evaluate``: JSON output, and one-line errors with exit code 2 for bad input."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import ROOT

BASE = ["--lanes-side", "1", "--patches-ahead", "10", "--patches-behind", "0"]


def run_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "sim.evaluate", *args], cwd=ROOT, capture_output=True, text=True, timeout=600
    )


def test_json_output_has_the_contract_fields():
    proc = run_cli(
        "--ruleset",
        "v2",
        "--protocol",
        "custom",
        "--runs",
        "8",
        "--frames",
        "300",
        "--policy",
        "heuristic_a",
        *BASE,
        "--other-agents",
        "3",
        "--json",
    )
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    for key in ("scores", "median_site", "median", "mean", "ci95"):
        assert key in out
    assert len(out["scores"]) == 8 and out["other_agents"] == 3
    assert out["ci95"][0] <= out["mean"] <= out["ci95"][1]


def test_human_readable_summary():
    proc = run_cli(
        "--ruleset",
        "v1",
        "--protocol",
        "custom",
        "--runs",
        "2",
        "--frames",
        "60",
        "--policy",
        "noop",
        "--lanes-side",
        "0",
        "--patches-ahead",
        "1",
        "--patches-behind",
        "0",
    )
    assert proc.returncode == 0, proc.stderr
    assert "site median" in proc.stdout and "frames/s" in proc.stdout


def _policy_file(tmp_path: Path, body: str) -> str:
    path = tmp_path / "user_policy.py"
    path.write_text(body)
    return str(path)


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (["--ruleset", "v3", "--protocol", "custom", "--policy", "noop", *BASE], "--ruleset"),
        (["--ruleset", "v2", "--protocol", "official", "--policy", "noop", *BASE], "--protocol"),
        (["--ruleset", "v1", "--protocol", "v2-official", "--policy", "noop", *BASE], "--protocol"),
        (
            [
                "--ruleset",
                "v2",
                "--protocol",
                "custom",
                "--policy",
                "noop",
                "--lanes-side",
                "99",
                "--patches-ahead",
                "1",
                "--patches-behind",
                "0",
            ],
            "--lanes-side",
        ),
        (["--ruleset", "v2", "--protocol", "custom", "--frames", "0", "--policy", "noop", *BASE], "--frames"),
        (["--ruleset", "v2", "--protocol", "custom", "--runs", "-3", "--policy", "noop", *BASE], "--runs"),
        (
            ["--ruleset", "v2", "--protocol", "custom", "--policy", "noop", *BASE, "--other-agents", "11"],
            "--other-agents",
        ),
        (
            ["--ruleset", "v1", "--protocol", "custom", "--policy", "noop", *BASE, "--other-agents", "2"],
            "--other-agents",
        ),
        (["--ruleset", "v2", "--protocol", "custom", "--policy", "nosuchpolicy", *BASE], "--policy"),
        (["--ruleset", "v2", "--protocol", "custom", "--policy", "missing.py:f", *BASE], "--policy"),
        (
            [
                "--ruleset",
                "v2",
                "--protocol",
                "custom",
                "--policy",
                "heuristic_a",
                "--lanes-side",
                "0",
                "--patches-ahead",
                "1",
                "--patches-behind",
                "0",
            ],
            "--policy",
        ),
        (
            [
                "--ruleset",
                "v2",
                "--protocol",
                "custom",
                "--policy",
                "noop",
                "--lanes-side",
                "x",
                "--patches-ahead",
                "1",
                "--patches-behind",
                "0",
            ],
            "--lanes-side",
        ),
    ],
)
def test_bad_arguments_exit_2_with_one_line(args, needle):
    proc = run_cli(*args)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0], proc.stderr
    assert "Traceback" not in proc.stderr


@pytest.mark.parametrize(
    ("body", "needle"),
    [
        ("def f(obs):\n    raise RuntimeError('boom')\nimport nonexistent_module_xyz\n", "could not load"),
        ("x = 1\n", "no callable"),
        ("import numpy as np\ndef f(obs):\n    return np.zeros(len(obs) + 1, dtype=int)\n", "shape"),
        ("import numpy as np\ndef f(obs):\n    return np.full(len(obs), 7)\n", "action 7"),
        ("import numpy as np\ndef f(obs):\n    return np.full(len(obs), 1.5)\n", "non-integer"),
    ],
)
def test_bad_policy_files(tmp_path, body, needle):
    spec = _policy_file(tmp_path, body) + ":f"
    proc = run_cli("--ruleset", "v2", "--protocol", "custom", "--runs", "2", "--frames", "60", "--policy", spec, *BASE)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "--policy" in lines[0] and needle in lines[0], proc.stderr


def test_user_policy_file_runs(tmp_path):
    body = "import numpy as np\ndef f(obs):\n    return np.where(obs.inputs[:, 28] >= 1.0, 1, 3)\n"
    proc = run_cli(
        "--ruleset",
        "v2",
        "--protocol",
        "custom",
        "--runs",
        "4",
        "--frames",
        "200",
        "--policy",
        _policy_file(tmp_path, body) + ":f",
        *BASE,
        "--json",
    )
    assert proc.returncode == 0, proc.stderr
    assert len(json.loads(proc.stdout.splitlines()[-1])["scores"]) == 4
