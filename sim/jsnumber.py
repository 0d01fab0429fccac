"""JavaScript's ``String(x)`` of a number (ECMAScript Number::toString), written once.

Two originals depend on it: the site's "median" sorts the run scores as strings (``Array.prototype.sort``
without a comparator, ``sim.protocols.site_median``), and ``JSON.stringify`` writes every weight of
a convnetjs net this way (``autotune.convnet.netjson``). The shortest round-trip digits are
Python's ``repr``; only the layout differs: JS writes plain decimals for 1e-6 ≤ |x| < 1e21
(``0.00005``, where Python writes ``5e-05``) and exponents without padding (``1e-7``, ``1e+21``).
"""

from __future__ import annotations

import decimal
import math

__all__ = ["js_number_to_string"]


def js_number_to_string(x: float) -> str:
    """``String(x)`` of a JS number: ``NaN``, ``Infinity``, ``-Infinity`` included."""
    x = float(x)
    if math.isnan(x):
        return "NaN"
    if math.isinf(x):
        return "Infinity" if x > 0 else "-Infinity"
    if x == 0.0:
        return "0"
    r = repr(x)
    if "e" not in r:  # Python prints plain decimals for 1e-4 ≤ |x| < 1e16, where JS does too
        return r[:-2] if r.endswith(".0") else r
    sign, digits, exponent = decimal.Decimal(r).as_tuple()
    ds = "".join(map(str, digits)).rstrip("0")
    exp = int(exponent) + len(digits) - len(ds)
    k = len(ds)
    n = exp + k  # x = 0.ds × 10^n
    neg = "-" if sign else ""
    if k <= n <= 21:
        body = ds + "0" * (n - k)
    elif 0 < n <= 21:
        body = ds[:n] + "." + ds[n:]
    elif -6 < n <= 0:
        body = "0." + "0" * (-n) + ds
    else:
        e = n - 1
        mant = ds if k == 1 else ds[0] + "." + ds[1:]
        body = f"{mant}e{'+' if e >= 0 else '-'}{abs(e)}"
    return neg + body
