"""Exact convnetjs prediction-mode forward pass (float64, numba), for any ``ConvNet``.

The network is flattened into two arrays so that one compiled function evaluates every net:

* ``codes`` int64 (n_layers, 5): ``[layer code, n_in, n_out, offset into params, aux]``;
* ``params`` float64: per fc its weights stored transposed (row-major (in, out)) then its biases; a dropout's
  ``drop_prob``; an lrn's ``k, alpha, beta`` (aux = n); a maxout's group size is its aux.

Arithmetic follows engine_spec.md §10.5/§10.9 operation by operation (no BLAS, no re-association,
no fused multiply-add): fc ``a = 0.0; a += x_d·w_id for d = 0…; a += b_i``; relu sets values < 0 to 0
(NaN passes); tanh ``(e^{2x} − 1)/(e^{2x} + 1)`` with ``exp``; sigmoid ``1/(1 + e^{−x})``; maxout
strict ``>`` from j = 0; dropout multiplies by ``drop_prob`` (the prediction-mode bug); svm and
regression are identities; softmax subtracts the maximum (strict ``>`` scan) and divides by the
in-order sum; lrn ``x_i / ((Σ x_j²)·(α/n) + k)^β``.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
from numba import njit

from autotune.convnet.deepqlearn import js_argmax_rows
from autotune.convnet.spec import (
    FC,
    LRN,
    SVM,
    ConvNet,
    Dropout,
    Input,
    Maxout,
    Regression,
    Relu,
    Sigmoid,
    Softmax,
    Tanh,
    layer_sizes,
)

L_INPUT, L_FC, L_RELU, L_TANH, L_SIGMOID, L_MAXOUT, L_DROPOUT, L_SVM, L_SOFTMAX, L_REGRESSION, L_LRN = range(11)
_CODES = {
    Input: L_INPUT,
    FC: L_FC,
    Relu: L_RELU,
    Tanh: L_TANH,
    Sigmoid: L_SIGMOID,
    Maxout: L_MAXOUT,
    Dropout: L_DROPOUT,
    SVM: L_SVM,
    Softmax: L_SOFTMAX,
    Regression: L_REGRESSION,
    LRN: L_LRN,
}
C_CODE, C_IN, C_OUT, C_OFF, C_AUX = range(5)


@dataclasses.dataclass(frozen=True)
class FlatNet:
    """A ``ConvNet`` as flat arrays for the compiled forward pass."""

    codes: np.ndarray  # int64 (n_layers, 5)
    params: np.ndarray  # float64
    input_size: int
    output_size: int
    max_width: int


def flatten(net: ConvNet) -> FlatNet:
    """Flatten a ``ConvNet`` (layer codes + one float64 parameter array)."""
    sizes = layer_sizes(net.layers)
    codes = np.zeros((len(net.layers), 5), dtype=np.int64)
    chunks: list[np.ndarray] = []
    offset = 0
    fc = 0
    for i, (layer, (n_in, n_out)) in enumerate(zip(net.layers, sizes, strict=True)):
        codes[i, C_CODE] = _CODES[type(layer)]
        codes[i, C_IN] = n_in
        codes[i, C_OUT] = n_out
        codes[i, C_OFF] = offset
        extra: np.ndarray | None = None
        if isinstance(layer, FC):
            w, b = net.params[fc]
            fc += 1
            extra = np.concatenate([w.T.reshape(-1), b])  # stored transposed: (in, out)
        elif isinstance(layer, Dropout):
            extra = np.array([float(layer.drop_prob)])
        elif isinstance(layer, LRN):
            extra = np.array([float(layer.k), float(layer.alpha), float(layer.beta)])
            codes[i, C_AUX] = int(layer.n)
        elif isinstance(layer, Maxout):
            codes[i, C_AUX] = int(layer.group_size)
        if extra is not None:
            chunks.append(extra)
            offset += extra.size
    params = np.ascontiguousarray(np.concatenate(chunks) if chunks else np.zeros(0), dtype=np.float64)
    width = max(max(a, b) for a, b in sizes)
    return FlatNet(codes, params, net.input_size, sizes[-1][1], width)


@njit(cache=True, error_model="numpy")
def forward_flat(codes: np.ndarray, params: np.ndarray, x: np.ndarray, buf: np.ndarray) -> int:
    """Forward ``x`` through the flat net; the output is ``buf[k, :n_out]`` for the returned k.

    ``buf`` is float64 (2, max_width) scratch (``x`` is copied into it first; ``x`` may be longer
    than the input layer: like convnetjs, an fc reads only its ``num_inputs`` first values).
    """
    n0 = codes[0, C_IN]
    for d in range(n0):
        buf[0, d] = x[d]
    src = 0
    for li in range(codes.shape[0]):
        code = codes[li, C_CODE]
        n_in = codes[li, C_IN]
        n_out = codes[li, C_OUT]
        off = codes[li, C_OFF]
        if code == L_INPUT or code == L_SVM or code == L_REGRESSION:
            continue
        dst = 1 - src
        if code == L_FC:
            # o_i = ((0 + x_0 w_i0) + x_1 w_i1) + … + b_i: every neuron's sum runs in index order d = 0…
            # as in convnetjs; looping d outside and i inside only interleaves independent sums
            # (bit-identical, and it vectorises across neurons).
            out = buf[dst, :n_out]
            x = buf[src, :n_in]
            wt = params[off : off + n_in * n_out].reshape((n_in, n_out))
            b = params[off + n_in * n_out : off + n_in * n_out + n_out]
            for i in range(n_out):
                out[i] = 0.0
            for d in range(n_in):
                xd = x[d]
                for i in range(n_out):
                    out[i] += xd * wt[d, i]
            for i in range(n_out):
                out[i] += b[i]
        elif code == L_RELU:
            for i in range(n_out):
                v = buf[src, i]
                buf[dst, i] = 0.0 if v < 0.0 else v
        elif code == L_TANH:
            for i in range(n_out):
                e = math.exp(2.0 * buf[src, i])
                buf[dst, i] = (e - 1.0) / (e + 1.0)
        elif code == L_SIGMOID:
            for i in range(n_out):
                buf[dst, i] = 1.0 / (1.0 + math.exp(-buf[src, i]))
        elif code == L_MAXOUT:
            g = codes[li, C_AUX]
            for i in range(n_out):
                ix = i * g
                a = buf[src, ix]
                for j in range(1, g):
                    a2 = buf[src, ix + j]
                    if a2 > a:
                        a = a2
                buf[dst, i] = a
        elif code == L_DROPOUT:
            p = params[off]
            for i in range(n_out):
                buf[dst, i] = buf[src, i] * p
        elif code == L_SOFTMAX:
            amax = buf[src, 0]
            for i in range(1, n_out):
                if buf[src, i] > amax:
                    amax = buf[src, i]
            esum = 0.0
            for i in range(n_out):
                e = math.exp(buf[src, i] - amax)
                esum += e
                buf[dst, i] = e
            for i in range(n_out):
                buf[dst, i] = buf[dst, i] / esum
        elif code == L_LRN:
            n = codes[li, C_AUX]
            k = params[off]
            alpha = params[off + 1]
            beta = params[off + 2]
            n2 = n // 2
            for i in range(n_out):
                den = 0.0
                lo = i - n2 if i - n2 > 0 else 0
                hi = i + n2 if i + n2 < n_out - 1 else n_out - 1
                for j in range(lo, hi + 1):
                    aa = buf[src, j]
                    den += aa * aa
                den *= alpha / n
                den += k
                den = math.pow(den, beta)
                buf[dst, i] = buf[src, i] / den
        src = dst
    return src


@njit(cache=True, error_model="numpy")
def forward_batch_flat(codes: np.ndarray, params: np.ndarray, xs: np.ndarray, out: np.ndarray, max_width: int) -> None:
    buf = np.empty((2, max_width))
    n_out = codes[codes.shape[0] - 1, C_OUT]
    for r in range(xs.shape[0]):
        k = forward_flat(codes, params, xs[r], buf)
        for j in range(n_out):
            out[r, j] = buf[k, j]


def forward(net: ConvNet | FlatNet, x: np.ndarray) -> np.ndarray:
    """Exact convnetjs outputs for one input vector (1-D) or a batch (2-D, one row per input)."""
    flat = net if isinstance(net, FlatNet) else flatten(net)
    xs = np.ascontiguousarray(x, dtype=np.float64)
    single = xs.ndim == 1
    if single:
        xs = xs[None, :]
    if xs.shape[1] < flat.input_size:
        raise ValueError(f"forward: input has {xs.shape[1]} values, the net needs {flat.input_size}")
    out = np.empty((xs.shape[0], flat.output_size))
    forward_batch_flat(flat.codes, flat.params, xs, out, flat.max_width)
    return out[0] if single else out


def greedy_actions(net: ConvNet | FlatNet, x: np.ndarray, num_actions: int = 5) -> np.ndarray:
    """deepqlearn's greedy action (first maximal Q among the first ``num_actions`` outputs) per row."""
    q = np.atleast_2d(forward(net, x))
    return js_argmax_rows(np.ascontiguousarray(q[:, :num_actions])).astype(np.int64)
