"""The compiled rollout loops (numba), in float32 like the trained network.

Two loops, one per shape of work (measured in docs/BENCHMARKS.md): `roll_voices` runs one voice at a time with
matrix-vector products and is the faster for a few voices; `roll_batch` advances every voice one window at a time with
BLAS matrix products for the branch, the faster from about eight voices on. Voices may play at different pitches
(per-voice bases). `rollout._roll_numpy` is the same loop in numpy, used when importing numba would cost more than
it saves. Both report, per voice, the first sample of the window
where it failed and why (FAIL_NONFINITE, FAIL_DOMAIN) into `fail`, which the caller fills with (-1, 0) beforehand; a
failed voice stops there, the others go on.

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
def _check(b, start, n, n_samples, nq, np_, check, box, mask, fail):
    if not (math.isfinite(nq) and math.isfinite(np_)):
        fail[b, 0] = start
        fail[b, 1] = FAIL_NONFINITE
        return False
    if check and start + n < n_samples and not _in_domain(nq, np_, box, mask):
        fail[b, 0] = start + n
        fail[b, 1] = FAIL_DOMAIN
        return False
    return True


@numba.njit(**_JIT)
def roll_voices(x0, n_samples, spw, n_lo, vidx, Bq, Bp, endb, endlin, center, halfrange, ff, pin, gain, Gw, Gb, Hw,
                Hb, Ow, Ob, box, mask, check, q_out, p_out, fail):
    """One voice after another, matrix-vector products.

    Gw, Gb: the weights of the modified MLP's gates U, V and first layer side by side; Hw, Hb: the other hidden
    layers; Ow, Ob: the output layer; all float32.
    Voice b plays at the sample spacing (pitch) vidx[b] of the stacked bases: spw (P,) samples per window, n_lo (P,);
    Bq, Bp: (P, k + 3, n_max) float32, the trunk features times s c at the window's sample offsets, then the rows
    cos, sin and bias (zero-padded past each spacing's n_hi), so that a window's samples are [o_q, q0, p0, 1] @ Bq
    and [o_p, p0, -q0, 1] @ Bp. A window holds n_lo = floor(spw) or n_hi = ceil(spw) samples (see window_end);
    endb (P, 2, 2, k) and endlin (P, 2, 6) give the end state after each of the two lengths.
    pin (B, W, n_par) float64: each window's bow inputs (n_par 0 for a point model), gain (B, W): the correction's
    factor per window, center and halfrange (B, W, 2): the state's scaling per window (npnet.state_scaling)
    (rollout.window_inputs); a voice's windows past W reuse its last.
    """
    k = endb.shape[3]
    width = Hw.shape[1]
    h = np.empty(ff.shape[1] * 2, np.float32)
    g = np.empty(3 * width, np.float32)
    u = np.empty(width, np.float32)
    v = np.empty(width, np.float32)
    z = np.empty(width, np.float32)
    hh = np.empty(width, np.float32)
    o = np.empty(2 * k, np.float32)
    for b in range(x0.shape[0]):
        P = vidx[b]
        q0 = x0[b, 0]
        p0 = x0[b, 1]
        start = 0
        win = 0
        while start < n_samples:
            n = window_end(win, spw[P]) - start
            wi = min(win, pin.shape[1] - 1)
            _features(q0, p0, center[b, wi], halfrange[b, wi], ff, pin[b, wi], h)
            _dense(h, Gw, Gb, g)
            for j in range(width):  # modified MLP: h = v + tanh(z) (u - v); u is kept as u - v
                vv = tanh32(g[width + j])
                u[j] = tanh32(g[j]) - vv
                v[j] = vv
                hh[j] = vv + tanh32(g[2 * width + j]) * u[j]
            for layer in range(Hw.shape[0]):
                _dense(hh, Hw[layer], Hb[layer], z)
                for j in range(width):
                    hh[j] = v[j] + tanh32(z[j]) * u[j]
            _dense(hh, Ow, Ob, o)
            gw = gain[b, wi]
            for j in range(2 * k):
                o[j] *= gw
            m = min(n, n_samples - start)
            _samples(q0, p0, o, gw, Bq[P], Bp[P], m, q_out[b, start:start + m], p_out[b, start:start + m])
            q0, p0 = _end_state(q0, p0, o[:k], o[k:], gw, endb[P, n - n_lo[P]], endlin[P, n - n_lo[P]])
            if not _check(b, start, n, n_samples, q0, p0, check, box, mask, fail):
                break
            start += n
            win += 1


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


@numba.njit(**_JIT)
def roll_batch(x0, n_samples, spw, n_lo, vidx, Bq, Bp, endb, endlin, center, halfrange, ff, pin, gain, Gw, Gb, Hw,
               Hb, Ow, Ob, box, mask, check, q_out, p_out, fail):
    """All voices one window at a time, the branch as matrix-matrix products (BLAS) over the voices. Same arguments
    as `roll_voices`; voices may play at different pitches.

    Two passes per block of BLOCK windows: the chain (branch outputs and end states of every voice), then the
    samples voice by voice, so that a pitch's basis (~240 KB) stays in cache over the block; writing each window's
    samples inside the chain touched every pitch's basis per window (23 MB for 100 pitches: memory-bound).
    """
    B = x0.shape[0]
    k = endb.shape[3]
    x = x0.copy()
    H = np.empty((B, ff.shape[1] * 2), np.float32)
    width = Hw.shape[1]
    U = np.empty((B, width), np.float32)
    V = np.empty((B, width), np.float32)
    h = np.empty((B, width), np.float32)
    O_blk = np.empty((B, BLOCK, 2 * k), np.float32)
    X_blk = np.empty((B, BLOCK, 2), np.float64)
    G_blk = np.empty((B, BLOCK), np.float64)
    last_w = pin.shape[1] - 1
    S_blk = np.empty((B, BLOCK), np.int64)  # each window's first sample, -1 where the voice computed none
    alive = np.ones(B, np.bool_)
    start = np.zeros(B, np.int64)
    win = 0
    running = B
    while running > 0:
        nb = 0
        S_blk[:] = -1
        while nb < BLOCK and running > 0:
            wi = min(win, last_w)
            for b in range(B):
                _features(x[b, 0], x[b, 1], center[b, wi], halfrange[b, wi], ff, pin[b, wi], H[b])
            G = np.dot(H, Gw)
            for b in range(B):  # modified MLP: h = v + tanh(z) (u - v); U is kept as u - v
                for j in range(width):
                    vv = tanh32(G[b, width + j] + Gb[width + j])
                    U[b, j] = tanh32(G[b, j] + Gb[j]) - vv
                    V[b, j] = vv
                    h[b, j] = vv + tanh32(G[b, 2 * width + j] + Gb[2 * width + j]) * U[b, j]
            for layer in range(Hw.shape[0]):
                Z = np.dot(h, Hw[layer])
                bias = Hb[layer]
                for b in range(B):
                    for j in range(width):
                        h[b, j] = V[b, j] + tanh32(Z[b, j] + bias[j]) * U[b, j]
            O = np.dot(h, Ow)
            running = 0
            for b in range(B):
                if not alive[b] or start[b] >= n_samples:
                    continue
                P = vidx[b]
                n = window_end(win, spw[P]) - start[b]
                o = O_blk[b, nb]
                g = gain[b, wi]
                for kk in range(2 * k):
                    o[kk] = (O[b, kk] + Ob[kk]) * g
                X_blk[b, nb, 0] = x[b, 0]
                X_blk[b, nb, 1] = x[b, 1]
                G_blk[b, nb] = g
                S_blk[b, nb] = start[b]
                nq, np_ = _end_state(x[b, 0], x[b, 1], o[:k], o[k:], g, endb[P, n - n_lo[P]],
                                     endlin[P, n - n_lo[P]])
                if _check(b, start[b], n, n_samples, nq, np_, check, box, mask, fail):
                    x[b, 0] = nq
                    x[b, 1] = np_
                    start[b] += n
                    if start[b] < n_samples:
                        running += 1
                else:  # park the stopped voice where the network is defined, so the batch's products stay finite
                    alive[b] = False
                    x[b, 0] = center[b, wi, 0]
                    x[b, 1] = center[b, wi, 1]
            nb += 1
            win += 1
        for b in range(B):
            P = vidx[b]
            for i in range(nb):
                s0 = S_blk[b, i]
                if s0 < 0:
                    continue
                m = min(window_end(win - nb + i, spw[P]) - s0, n_samples - s0)
                _samples(X_blk[b, i, 0], X_blk[b, i, 1], O_blk[b, i], G_blk[b, i], Bq[P], Bp[P], m,
                         q_out[b, s0:s0 + m], p_out[b, s0:s0 + m])
