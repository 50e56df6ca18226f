"""A window's pieces in numba, float32 like the trained network: the branch's features and layers, the in-box test,
a window's end and its samples. The live engine's block loop (`voices`) and the operator's pitch-curve path are
built from them; whole renders run the compiled core (src/core) instead. Numba stays a dependency for these two
paths until the core carries them (issue 23).

Why not numpy's or libm's tanh, cos and sin: numba calls libm one value at a time, which took most of a window's time.
The versions here are plain arithmetic, so LLVM vectorises them; `error_model="numpy"` drops numba's zero-division
branch, without which no loop holding a division vectorises. The flags leave out nnan/ninf, so a NaN still reaches
the finiteness check.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from .windows import FAIL_DOMAIN, FAIL_NONFINITE  # noqa: F401  (compile-time constants here)

_F = np.float32
# tanh(x) ~ x P(x^2) / Q(x^2) on [-9, 9] (beyond, tanh is 1 to float32 precision): a rational least-squares fit made
# for this module; max error 2.6e-8 in float64, 3.4e-7 evaluated in float32 (tests/test_kernels.py checks it)
_P0, _P1, _P2, _P3, _P4 = _F(0.99999993), _F(0.133792701), _F(0.00349369663), _F(2.05850838e-05), _F(1.33338945e-08)
_Q1, _Q2, _Q3, _Q4 = _F(0.467125736), _F(0.0258692958), _F(0.00032828556), _F(7.76546335e-07)
_NINE, _ONE = _F(9.0), _F(1.0)
# cos, sin: reduce to [-pi, pi], then the Taylor series to r^23 (error < 1e-11 there)
_TWO_PI = 2 * math.pi
_INV_TWO_PI = 1 / _TWO_PI
_COS = np.array([(-1) ** i / math.factorial(2 * i) for i in range(12)])
_SIN = np.array([(-1) ** i / math.factorial(2 * i + 1) for i in range(12)])

_FM = {"contract", "arcp", "nsz", "afn", "reassoc"}
_JIT = dict(fastmath=_FM, error_model="numpy", cache=True)


@numba.njit(**_JIT)
def tanh32(x):
    x = _NINE if x > _NINE else x
    x = -_NINE if x < -_NINE else x
    z = x * x
    p = (((_P4 * z + _P3) * z + _P2) * z + _P1) * z + _P0
    q = (((_Q4 * z + _Q3) * z + _Q2) * z + _Q1) * z + _ONE
    y = x * p / q
    y = _ONE if y > _ONE else y
    return -_ONE if y < -_ONE else y


@numba.njit(**_JIT)
def cos_sin(z):
    r = z - math.floor(z * _INV_TWO_PI + 0.5) * _TWO_PI
    r2 = r * r
    c = _COS[11]
    s = _SIN[11]
    for i in range(10, -1, -1):
        c = c * r2 + _COS[i]
        s = s * r2 + _SIN[i]
    return c, s * r


@numba.njit(**_JIT)
def _features(q, p, center, halfrange, ff, pin, h):
    """The branch's Fourier features of the state (q, p) and, for a range model, the window's bow inputs pin
    (npnet.param_inputs; empty for a point model) into h: cos then sin."""
    a0 = (q - center[0]) / halfrange[0]
    a1 = (p - center[1]) / halfrange[1]
    m = ff.shape[1]
    for i in range(m):
        z = a0 * ff[0, i] + a1 * ff[1, i]
        for j in range(pin.shape[0]):
            z += pin[j] * ff[2 + j, i]
        c, s = cos_sin(z)
        h[i] = c
        h[m + i] = s


@numba.njit(**_JIT)
def _dense(h, W, b, out):
    for j in range(out.shape[0]):
        out[j] = b[j]
    for i in range(h.shape[0]):
        hi = h[i]
        for j in range(out.shape[0]):
            out[j] += hi * W[i, j]


@numba.njit(**_JIT)
def _in_domain(q, p, box, mask):
    if not (box[0] <= q <= box[1] and box[2] <= p <= box[3]):
        return False
    g = mask.shape[0]
    i = min(max(int((q - box[0]) / (box[1] - box[0]) * g), 0), g - 1)
    j = min(max(int((p - box[2]) / (box[3] - box[2]) * g), 0), g - 1)
    return mask[i, j]


@numba.njit(**_JIT)
def window_end(w, spw):
    """First sample after window w: window w starts at the sample nearest w T (spw = T / sample spacing), so a window
    holds floor(spw) or ceil(spw) samples and the starts never drift from the multiples of T the model trained on."""
    return int(math.floor((w + 1) * spw + 0.5))


@numba.njit(**_JIT)
def _end_state(q0, p0, oq, op, g, endb, endlin):
    """The window's end state in float64: the linear flow plus the correction at the last offset (oq, op already
    times the range model's gain g, which the bias term takes here)."""
    nq = q0 * endlin[0] + p0 * endlin[1] + g * endlin[2]
    np_ = p0 * endlin[4] - q0 * endlin[5] + g * endlin[3]
    for kk in range(endb.shape[1]):
        nq += oq[kk] * endb[0, kk]
        np_ += op[kk] * endb[1, kk]
    return nq, np_


@numba.njit(**_JIT)
def _samples(q0, p0, o, g, Bq, Bp, m, qrow, prow):
    """A window's m samples: the linear flow, the bias (times the gain g) and the correction o (2k) over the basis
    rows."""
    k = o.shape[0] // 2
    qf = np.float32(q0)
    pf = np.float32(p0)
    gf = np.float32(g)
    c, s = Bq[k], Bq[k + 1]
    cp, sp = Bp[k], Bp[k + 1]  # the rotation's cos and sin again, or the p rows of a linearised flow
    biasq, biasp = Bq[k + 2], Bp[k + 2]
    for j in range(m):
        qrow[j] = qf * c[j] + pf * s[j] + gf * biasq[j]
    for j in range(m):
        prow[j] = pf * cp[j] - qf * sp[j] + gf * biasp[j]
    for kk in range(k):
        w = o[kk]
        row = Bq[kk]
        for j in range(m):
            qrow[j] += w * row[j]
    for kk in range(k):
        w = o[k + kk]
        row = Bp[kk]
        for j in range(m):
            prow[j] += w * row[j]


BLOCK = 64  # windows per pass of roll_batch


