"""What a score is: its engine, other agents and kind, named the same way in every figure, table and note.

A DeepTraffic score means little without three facts: the engine it came from (v1, 2017: one car;
v2, 2018–19: up to 10 other agents sharing the net), the other agents on the road, and whether it
was *measured* (a net scored by the exact engine with the official protocol) or *self-reported*
(the crowd's claims, whose kinds the crowd CSV records in ``score_kind``). The report never puts
two of these side by side without naming both; this module holds the names, the marker encoding
(symbol = engine, fill = measured) and the per-point hover record every figure carries.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

__all__ = [
    "ENGINES",
    "ENGINE_LABEL",
    "ENGINE_SYMBOL",
    "CLAIMED",
    "LOCAL",
    "APPROX",
    "EXAMPLE",
    "OWN_WEIGHTS",
    "REPLAYED",
    "SEARCHED",
    "KIND_LABEL",
    "MEASURED_KINDS",
    "CUSTOMDATA",
    "HOVER",
    "is_measured",
    "agents_label",
    "kinds_label",
    "engines_label",
    "series_name",
    "marker_symbol",
    "series_meta",
]

ENGINES = ("v1", "v2")
ENGINE_LABEL = {"v1": "v1 engine", "v2": "v2 engine"}
"""Engine → its name in the report (never bare 'v1': protocol names such as v1-original contain that)."""
ENGINE_SYMBOL = {"v1": "diamond", "v2": "circle"}

# score kinds: the crowd CSV's score_kind values (self-reported), then the measured ones
CLAIMED, LOCAL, APPROX, EXAMPLE = "claimed", "local", "approx", "official-example"
OWN_WEIGHTS = "own-weights"
"""A human net scored with its own trained weights in its own engine and official protocol."""
REPLAYED = "replayed"
"""A crowd setting retrained by our learner (its own engine, ≥ 1 seed) and scored with the official protocol."""
SEARCHED = "search"
"""A trial of an automated study: trained by our learner, scored with the official protocol."""
KIND_LABEL = {
    CLAIMED: "claimed",
    LOCAL: "local run (self-reported)",
    APPROX: "approximate or lower bound (self-reported)",
    EXAMPLE: "official example (self-reported)",
    OWN_WEIGHTS: "measured: own weights",
    REPLAYED: "measured: replayed by our learner",
    SEARCHED: "measured: automated search",
}
"""Kind → its name in the report; no label is part of another, so a name that holds one names that kind."""
MEASURED_KINDS = frozenset({OWN_WEIGHTS, REPLAYED, SEARCHED})
CUSTOMDATA = ("label", "engine", "agents", "kind", "confidence")
"""Fields of every data point's ``customdata`` row, in order (the agents filter reads ``agents``)."""
HOVER = (
    "%{customdata[0]}<br>%{y:.2f} mph · %{customdata[3]}<br>%{customdata[1]}, %{customdata[2]}"
    "<br>confidence: %{customdata[4]}<extra>%{fullData.name}</extra>"
)
"""Hover template naming a point's engine, agents, kind and confidence."""


def is_measured(kind: str) -> bool:
    """Whether a score of this kind was measured by the exact engine (else it is self-reported)."""
    if kind not in KIND_LABEL:
        raise ValueError(f"score kind {kind!r} is not one of {', '.join(KIND_LABEL)}")
    return kind in MEASURED_KINDS


def agents_label(engine: str, agents: int | None) -> str:
    """'no other agents (v1 engine)' for v1, else 'N other agents' ('agents unknown' when not recorded)."""
    if engine == "v1":
        return "no other agents (v1 engine)"
    if agents is None:
        return "other agents unknown"
    return f"{agents} other agent{'' if agents == 1 else 's'}"


def _ordered(values: Iterable[str], order: Sequence[str]) -> list[str]:
    present = set(values)
    return [v for v in order if v in present] + sorted(present - set(order))


def kinds_label(kinds: Iterable[str]) -> str:
    """The kinds' labels joined with ' + ' in a fixed order."""
    return " + ".join(KIND_LABEL[k] for k in _ordered(kinds, tuple(KIND_LABEL)))


def engines_label(engines: Iterable[str]) -> str:
    """The engines' labels joined with ' + '."""
    return " + ".join(ENGINE_LABEL[e] for e in _ordered(engines, ENGINES))


def series_name(side: str, engines: Iterable[str], kinds: Iterable[str], extra: str = "") -> str:
    """A trace or table row name that names its side, every engine and every score kind in it."""
    name = f"{side}: {engines_label(engines)} · {kinds_label(kinds)}"
    return f"{name} · {extra}" if extra else name


def marker_symbol(engine: str, kind: str) -> str:
    """Symbol by engine, filled when measured, open when self-reported."""
    symbol = ENGINE_SYMBOL[engine]
    return symbol if is_measured(kind) else f"{symbol}-open"


def series_meta(engines: Iterable[str], kinds: Iterable[str], *, filterable: bool = False) -> dict[str, object]:
    """A trace's ``meta``: the engines and kinds of its data (the trace-naming test reads it), and whether the
    agents filter applies to its points."""
    return {
        "engines": _ordered(engines, ENGINES),
        "kinds": _ordered(kinds, tuple(KIND_LABEL)),
        "filterable": filterable,
    }
