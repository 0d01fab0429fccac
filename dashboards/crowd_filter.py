"""``--filter``: choose crowd submissions with a small expression over their CSV columns, never ``eval``.

``engine_version == 'v2' and reported_score_mph > 70`` — names are CSV columns (or the record's
field names), values numbers, strings, True/False/None and lists of those; the expression is parsed
with ``ast`` and only the nodes listed in ``compile_filter`` are evaluated. A bad filter is a
``FilterError`` (a ``ConfigError``): one line naming the problem and, for an unknown column, the
nearest one.
"""

from __future__ import annotations

import ast
import difflib
import operator
from collections.abc import Callable, Sequence
from typing import Any

from dashboards.crowd_data import Submission
from sim.config import ConfigError

__all__ = ["FilterError", "compile_filter", "row_namespace", "select"]


class FilterError(ConfigError):
    """A --filter expression that is not allowed or names an unknown column."""


_COMPARE: dict[type, Callable[[Any, Any], bool]] = {
    ast.Eq: operator.eq,
    ast.NotEq: operator.ne,
    ast.Lt: operator.lt,
    ast.LtE: operator.le,
    ast.Gt: operator.gt,
    ast.GtE: operator.ge,
    ast.In: lambda a, b: a in b,
    ast.NotIn: lambda a, b: a not in b,
    ast.Is: operator.is_,
    ast.IsNot: operator.is_not,
}
_ARITH: dict[type, Callable[[Any, Any], Any]] = {
    ast.Add: operator.add,
    ast.Sub: operator.sub,
    ast.Mult: operator.mul,
    ast.Div: operator.truediv,
}


def compile_filter(expr: str, columns: list[str]) -> Callable[[dict[str, Any]], bool]:
    """A predicate over a row mapping (column → value) from a restricted expression.

    Allowed: column names, numbers, strings, True/False/None, lists/tuples of those, ``and or not``,
    comparisons (``== != < <= > >= in not in is is not``) and ``+ - * /``. A comparison with a blank
    (None) cell is False, except ``==``/``!=``/``is``.
    """
    try:
        tree = ast.parse(expr, mode="eval")
    except SyntaxError as exc:
        raise FilterError(f"--filter: not an expression ({exc.msg} at column {exc.offset}): {expr!r}") from None

    def check(node: ast.AST) -> None:
        if isinstance(node, ast.Name):
            if node.id not in columns and node.id not in ("True", "False", "None"):
                near = difflib.get_close_matches(node.id, columns, n=1)
                hint = f"; did you mean '{near[0]}'?" if near else ""
                raise FilterError(f"--filter: unknown column '{node.id}'{hint}")
            return
        allowed = (
            ast.Expression,
            ast.BoolOp,
            ast.And,
            ast.Or,
            ast.UnaryOp,
            ast.Not,
            ast.USub,
            ast.Compare,
            ast.Constant,
            ast.List,
            ast.Tuple,
            ast.Load,
            ast.BinOp,
            *_COMPARE,
            *_ARITH,
        )
        if not isinstance(node, allowed):
            raise FilterError(f"--filter: {type(node).__name__} is not allowed in a filter: {expr!r}")
        for child in ast.iter_child_nodes(node):
            check(child)

    check(tree)

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
            return None if inner is None else -inner
        if isinstance(node, ast.BinOp):
            left, right = value(node.left, row), value(node.right, row)
            if left is None or right is None:
                return None
            return _ARITH[type(node.op)](left, right)
        assert isinstance(node, ast.Compare)
        left = value(node.left, row)
        for op, comparator in zip(node.ops, node.comparators, strict=True):
            right = value(comparator, row)
            if (left is None or right is None) and not isinstance(op, (ast.Eq, ast.NotEq, ast.Is, ast.IsNot)):
                return False
            try:
                if not _COMPARE[type(op)](left, right):
                    return False
            except TypeError:
                raise FilterError(f"--filter: cannot compare {left!r} with {right!r} in {expr!r}") from None
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
