"""``--filter``: choose crowd submissions with a small expression over their CSV columns, never ``eval``.

``engine_version == 'v2' and reported_score_mph > 70`` — names are CSV columns (or the record's
field names), values numbers, strings, True/False/None and lists of those; the expression is parsed
with ``ast`` and only the nodes listed in ``compile_filter`` are evaluated. Everything a filter can
build is bounded — the expression's length (so every literal) and nesting, every integer, and every
string, list or number ``+`` and ``*`` make — so no filter can exhaust memory or time. A bad filter is a
``FilterError`` (a ``ConfigError``): one line naming the problem and, for an unknown column, the
nearest one; so is a filter that cannot be evaluated on a row (``lanesSide / 0``,
``engine_version + 1``), naming the sub-expression and the submission.
"""

from __future__ import annotations

import ast
import difflib
import operator
from collections.abc import Callable, Sequence
from typing import Any

from dashboards.crowd_data import Submission
from sim.config import ConfigError

__all__ = [
    "MAX_DEPTH",
    "MAX_EXPRESSION",
    "MAX_INT_BITS",
    "MAX_SIZE",
    "FilterError",
    "compile_filter",
    "row_namespace",
    "select",
]

MAX_EXPRESSION = 2000
"""Longest filter [characters]: what bounds every string and list written in it."""
MAX_DEPTH = 64
"""Deepest nesting of a filter's syntax tree [levels]."""
MAX_SIZE = 10_000
"""Largest string or list a filter may build with ``+`` / ``*`` [characters, or items counting nested ones]."""
MAX_INT_BITS = 256
"""Largest integer a filter may write or build with ``*`` [bits]; CSV values are far smaller."""


class FilterError(ConfigError):
    """A --filter expression that is not allowed, names an unknown column, or cannot be evaluated on a row."""


_COMPARE: dict[type, Callable[[Any, Any], bool]] = {
    ast.Eq: operator.eq,
    ast.NotEq: operator.ne,
    ast.Lt: operator.lt,
    ast.LtE: operator.le,
    ast.Gt: operator.gt,
    ast.GtE: operator.ge,
    ast.In: lambda a, b: a in b,
    ast.NotIn: lambda a, b: a not in b,
}
_ARITH: dict[type, Callable[[Any, Any], Any]] = {
    ast.Add: operator.add,
    ast.Sub: operator.sub,
    ast.Mult: operator.mul,
    ast.Div: operator.truediv,
}
_SYMBOLS = {ast.Add: "+", ast.Sub: "-", ast.Mult: "*", ast.Div: "/"}
_ALLOWED = (
    ast.Expression, ast.BoolOp, ast.And, ast.Or, ast.UnaryOp, ast.Not, ast.USub, ast.Compare, ast.Constant,
    ast.List, ast.Tuple, ast.Load, ast.BinOp, *_COMPARE, *_ARITH,
)  # fmt: skip
_NAMES = {  # operators as typed; other nodes by their ast name (Call, Attribute, Subscript, …)
    "Pow": "'**'", "Mod": "'%'", "FloorDiv": "'//'", "MatMult": "'@'", "BitAnd": "'&'", "BitOr": "'|'",
    "BitXor": "'^'", "LShift": "'<<'", "RShift": "'>>'", "Invert": "'~'", "UAdd": "unary '+'",
}  # fmt: skip
_LITERALS = (str, int, float, bool, type(None))


def _short(v: Any) -> str:
    text = repr(v)
    return text if len(text) <= 40 else text[:37] + "..."


def _depth(tree: ast.AST) -> int:
    """The nesting depth of ``tree`` (counted without recursion: a deep tree must not overflow the stack)."""
    deepest, stack = 0, [(tree, 1)]
    while stack:
        node, d = stack.pop()
        deepest = max(deepest, d)
        stack.extend((child, d + 1) for child in ast.iter_child_nodes(node))
    return deepest


def _weight(v: Any) -> int:
    """A value's size: a string's characters, a list's items (nested ones counted), 1 for anything else."""
    if isinstance(v, str):
        return len(v)
    if isinstance(v, list):
        return 1 + sum(_weight(x) for x in v)
    return 1


def _too_big(left: Any, right: Any, op: ast.operator) -> str | None:
    """What ``left op right`` would make when that is beyond the bounds (None: within them)."""
    if isinstance(op, ast.Mult):
        for seq, n in ((left, right), (right, left)):
            if isinstance(seq, (str, list)) and isinstance(n, int):
                size = _weight(seq) * max(n, 0)
                if size > MAX_SIZE:
                    return f"a {'string' if isinstance(seq, str) else 'list'} of size {size:,} (at most {MAX_SIZE:,})"
                return None
        if isinstance(left, int) and isinstance(right, int):
            bits = left.bit_length() + right.bit_length()
            return f"an integer of up to {bits:,} bits (at most {MAX_INT_BITS})" if bits > MAX_INT_BITS else None
    if isinstance(op, ast.Add) and isinstance(left, (str, list)) and isinstance(right, (str, list)):
        size = _weight(left) + _weight(right)
        kind = "string" if isinstance(left, str) else "list"
        return f"a {kind} of size {size:,} (at most {MAX_SIZE:,})" if size > MAX_SIZE else None
    return None


def _source(node: ast.AST) -> str:
    text = ast.unparse(node)
    return text if len(text) <= 80 else text[:77] + "..."


def compile_filter(expr: str, columns: list[str]) -> Callable[[dict[str, Any]], bool]:
    """A predicate over a row mapping (column → value) from a restricted expression.

    Allowed: column names, numbers, strings, True/False/None, lists/tuples of those, ``and or not``,
    comparisons (``== != < <= > >= in not in``) and ``+ - * /``. ``is``/``is not`` are refused
    (identity, not equality: ``engine_version is 'v2'`` would select nothing): write ``==``/``!=``.
    A comparison with a blank (None) cell is False, except ``==``/``!=``; arithmetic with one is None.
    The predicate raises ``FilterError`` for a row it cannot evaluate (division by zero, ``'v2' + 1``).
    """
    if len(expr) > MAX_EXPRESSION:
        raise FilterError(f"--filter: {len(expr)} characters; a filter has at most {MAX_EXPRESSION}")
    try:
        tree = ast.parse(expr, mode="eval")
    except SyntaxError as exc:
        raise FilterError(f"--filter: not an expression ({exc.msg} at column {exc.offset}): {expr!r}") from None
    except (RecursionError, MemoryError):
        raise FilterError(f"--filter: nested too deeply (at most {MAX_DEPTH} levels)") from None
    if _depth(tree) > MAX_DEPTH:
        raise FilterError(f"--filter: nested too deeply (at most {MAX_DEPTH} levels)")

    for node in ast.walk(tree):
        if isinstance(node, ast.Name):
            if node.id not in columns:
                near = difflib.get_close_matches(node.id, columns, n=1)
                hint = f"; did you mean '{near[0]}'?" if near else ""
                raise FilterError(f"--filter: unknown column '{node.id}'{hint}")
        elif isinstance(node, (ast.Is, ast.IsNot)):
            word, use = ("is", "==") if isinstance(node, ast.Is) else ("is not", "!=")
            raise FilterError(
                f"--filter: '{word}' compares identity, not values (it would select nothing); use {use}, "
                f"e.g. engine_version {use} 'v2'"
            )
        elif isinstance(node, ast.Constant):
            v = node.value
            if not isinstance(v, _LITERALS):
                raise FilterError(f"--filter: {_short(v)}: only numbers, strings, True/False/None are values")
            if isinstance(v, int) and v.bit_length() > MAX_INT_BITS:
                raise FilterError(f"--filter: the number {_short(v)} is too large (at most {MAX_INT_BITS} bits)")
        elif not isinstance(node, _ALLOWED):
            name = type(node).__name__
            raise FilterError(f"--filter: {_NAMES.get(name, name)} is not allowed in a filter: {expr!r}")

    def fail(node: ast.AST, row: dict[str, Any], why: str) -> FilterError:
        where = f" for submission {row['id']}" if isinstance(row.get("id"), str) else ""
        return FilterError(f"--filter: cannot evaluate {_source(node)}{where}: {why}")

    def arith(node: ast.BinOp, left: Any, right: Any, row: dict[str, Any]) -> Any:
        too_big = _too_big(left, right, node.op)
        if too_big is not None:
            raise fail(node, row, f"it would make {too_big}")
        try:
            return _ARITH[type(node.op)](left, right)
        except (TypeError, ZeroDivisionError, OverflowError, ValueError) as exc:
            symbol = _SYMBOLS[type(node.op)]
            raise fail(node, row, f"{_short(left)} {symbol} {_short(right)}: {exc}") from None

    def value(node: ast.AST, row: dict[str, Any]) -> Any:
        if isinstance(node, ast.Expression):
            return value(node.body, row)
        if isinstance(node, ast.Constant):
            return node.value
        if isinstance(node, ast.Name):
            return row[node.id]
        if isinstance(node, (ast.List, ast.Tuple)):
            return [value(e, row) for e in node.elts]
        if isinstance(node, ast.BoolOp):
            parts = (bool(value(v, row)) for v in node.values)
            return all(parts) if isinstance(node.op, ast.And) else any(parts)
        if isinstance(node, ast.UnaryOp):
            inner = value(node.operand, row)
            if isinstance(node.op, ast.Not):
                return not inner
            if inner is None:
                return None
            if isinstance(inner, bool) or not isinstance(inner, (int, float)):
                raise fail(node, row, f"-{_short(inner)}: only a number has a sign")
            return -inner
        if isinstance(node, ast.BinOp):
            left, right = value(node.left, row), value(node.right, row)
            if left is None or right is None:
                return None
            return arith(node, left, right, row)
        assert isinstance(node, ast.Compare)
        left = value(node.left, row)
        for op, comparator in zip(node.ops, node.comparators, strict=True):
            right = value(comparator, row)
            if (left is None or right is None) and not isinstance(op, (ast.Eq, ast.NotEq)):
                return False
            try:
                if not _COMPARE[type(op)](left, right):
                    return False
            except TypeError:
                if isinstance(op, (ast.In, ast.NotIn)):
                    why = f"'in' looks in a list or a string, not in {_short(right)}"
                else:
                    why = f"cannot compare {_short(left)} with {_short(right)}"
                raise fail(node, row, why) from None
            left = right
        return True

    return lambda row: bool(value(tree, row))


def row_namespace(sub: Submission) -> dict[str, Any]:
    """A submission under its CSV column names and its record field names (what a filter may name)."""
    return dict(sub.namespace())


def select(subs: Sequence[Submission], expr: str = "", limit: int = 0) -> list[Submission]:
    """The submissions ``expr`` keeps ('' keeps all), in their order, at most ``limit`` of them (0: all)."""
    chosen = list(subs)
    if expr and chosen:
        keep = compile_filter(expr, list(row_namespace(chosen[0])))
        chosen = [s for s in chosen if keep(row_namespace(s))]
    return chosen[:limit] if limit else chosen
