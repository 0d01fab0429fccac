"""``python -m sim.evaluate``: score a policy with a named protocol.

    python -m sim.evaluate --ruleset v2 --protocol v2-official --policy heuristic_a \\
        --lanes-side 1 --patches-ahead 10 --patches-behind 0 --other-agents 10 --json

``--policy`` is a built-in name (noop, accelerate, decelerate, random, heuristic_a) or
``FILE.py:FUNCTION``, a callable ``f(obs) -> actions`` on observation batches (``obs.inputs``
(N, D), ``obs.lane`` (N,), …). With ``--json`` the last line is one JSON object with the per-run
``scores`` (run order), ``median_site`` (the original's lexicographic median), ``median``,
``mean``, ``ci95`` and timing. Bad arguments exit with code 2 and a one-line message: every bad
value is a ``ConfigError`` naming the option, turned into that line in ``main`` alone.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NoReturn

from sim.config import ConfigError, EngineConfig
from sim.policies import BUILTINS
from sim.protocols import PROTOCOLS, EvalResult, evaluate
from sim.simulator import Observation, PolicyError


def _fail(message: str) -> NoReturn:
    print(f"error: {message}", file=sys.stderr)
    raise SystemExit(2)


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:  # one line, exit 2, no usage dump
        _fail(message)


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="python -m sim.evaluate", description="Evaluate a DeepTraffic policy with a reference protocol.")
    p.add_argument("--ruleset", default="v2", help="v1 or v2 (default v2)")
    p.add_argument("--protocol", required=True, help=", ".join(PROTOCOLS))
    p.add_argument(
        "--seed",
        type=int,
        default=None,
        help=f"protocol seed (defaults: {', '.join(f'{p.name} {p.seed}' for p in PROTOCOLS.values())})",
    )
    p.add_argument(
        "--runs",
        type=int,
        default=None,
        help="number of runs (custom; overriding an official size is allowed but flagged)",
    )
    p.add_argument("--frames", type=int, default=None, help="frames per run")
    p.add_argument("--policy", required=True, help=f"built-in ({', '.join(BUILTINS)}) or FILE.py:FUNCTION")
    p.add_argument("--lanes-side", type=int, required=True)
    p.add_argument("--patches-ahead", type=int, required=True)
    p.add_argument("--patches-behind", type=int, required=True)
    p.add_argument("--other-agents", type=int, default=0, help="v2 only, 0–10")
    p.add_argument("--threads", type=int, default=None, help="worker threads for batched protocols")
    p.add_argument("--json", action="store_true", help="print one JSON object on the last line")
    return p


def load_policy(spec: str, config: EngineConfig) -> tuple[Callable[[Observation], Any], str]:
    """A built-in by name or ``FILE.py:FUNCTION``; raises ``ConfigError`` naming ``--policy``."""
    if spec in BUILTINS:
        try:
            return BUILTINS[spec].bind(config), spec
        except ValueError as exc:
            raise ConfigError(f"--policy: {exc}") from None
    if ":" not in spec:
        raise ConfigError(f"--policy: '{spec}' is neither a built-in ({', '.join(BUILTINS)}) nor FILE.py:FUNCTION")
    file_name, _, func_name = spec.rpartition(":")
    path = Path(file_name)
    if not path.is_file():
        raise ConfigError(f"--policy: file '{file_name}' does not exist")
    try:
        module_spec = importlib.util.spec_from_file_location(f"_user_policy_{path.stem}", path)
        if module_spec is None or module_spec.loader is None:
            raise ImportError("not a Python module")
        module = importlib.util.module_from_spec(module_spec)
        module_spec.loader.exec_module(module)
    except Exception as exc:  # any failure of user code is a usage error, reported in one line
        raise ConfigError(f"--policy: could not load '{file_name}': {type(exc).__name__}: {exc}") from None
    fn = getattr(module, func_name, None)
    if fn is None or not callable(fn):
        raise ConfigError(f"--policy: '{file_name}' has no callable '{func_name}'")
    return fn, spec


def _summary(result: EvalResult) -> str:
    lines = [
        f"policy {result.policy} · {result.ruleset} · protocol {result.protocol} · seed {result.seed} · "
        f"{result.runs} runs × {result.frames} frames · other_agents {result.other_agents}",
        f"  site median (original's lexicographic median): {result.median_site:.2f} mph",
        f"  median {result.median:.3f} · mean {result.mean:.3f} · std {result.std:.3f} · "
        f"95% CI of the mean [{result.ci95[0]:.3f}, {result.ci95[1]:.3f}] · "
        f"min {min(result.scores):.2f} · max {max(result.scores):.2f}",
        f"  {result.wall_seconds:.2f} s wall, {result.frames_per_second:,.0f} frames/s",
    ]
    if not result.official_size:
        lines.append("  note: run count or length differs from the protocol's official size")
    return "\n".join(lines)


def _as_option(exc: ConfigError, dashes: bool = False) -> ConfigError:
    """``field: problem`` as ``--field: problem`` (the option the user typed)."""
    field, _, rest = str(exc).partition(": ")
    if not rest:
        return exc
    return ConfigError(f"--{field.replace('_', '-') if dashes else field}: {rest}")


def main(argv: Sequence[str] | None = None) -> int:
    """Parse ``argv``, evaluate, print; a bad value (a ``ConfigError``) is one line on stderr and exit 2."""
    args = build_parser().parse_args(argv)
    try:
        return _run(args)
    except ConfigError as exc:
        _fail(str(exc))


def _run(args: argparse.Namespace) -> int:
    try:
        config = EngineConfig(
            ruleset=args.ruleset,
            lanes_side=args.lanes_side,
            patches_ahead=args.patches_ahead,
            patches_behind=args.patches_behind,
            other_agents=args.other_agents,
        )
    except ConfigError as exc:
        raise _as_option(exc, dashes=True) from None
    if args.protocol not in PROTOCOLS:
        raise ConfigError(f"--protocol: '{args.protocol}' is not a protocol; use one of {', '.join(PROTOCOLS)}")
    for name in ("runs", "frames", "threads"):
        value = getattr(args, name)
        if value is not None and value <= 0:
            raise ConfigError(f"--{name}: must be a positive integer, got {value}")
    policy, name = load_policy(args.policy, config)

    bar = None
    progress = None
    if not args.json and sys.stderr.isatty():
        from tqdm import tqdm

        bar = tqdm(total=0, unit="frame", unit_scale=True, desc="evaluating", file=sys.stderr)

        def progress(done: int, total: int) -> None:
            bar.total = total
            bar.n = done
            bar.refresh()

    try:
        result = evaluate(
            config,
            policy,
            args.protocol,
            seed=args.seed,
            runs=args.runs,
            frames=args.frames,
            threads=args.threads,
            policy_name=name,
            progress=progress,
        )
    except ConfigError as exc:
        raise _as_option(exc) from None
    except PolicyError as exc:
        raise ConfigError(f"--policy: {exc}") from None
    finally:
        if bar is not None:
            bar.close()
    if args.json:
        print(json.dumps(result.to_json()))
    else:
        print(_summary(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
