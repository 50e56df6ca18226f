"""Voices that run block by block (numba): the live engine's (`bowsynth.live.Stream`) and a pitch curve's
(`curve.render_curve`), run in place on arrays prepared beforehand (`bank.VoiceBank`), so that an audio callback creates
no array and calls no Python per window.

A window is computed by the rollout's own compiled pieces (`loops._features`, `_dense`, `tanh32`, `_samples`,
`_end_state`, `window_end`: the body of `loops.roll_voices`), and the FDM by `fdm_kernel.kernel` itself. What is new
here is only the bookkeeping a stream needs and a whole-render loop does not: a voice's window partition continues
across blocks (window w of a note starts at the sample nearest w T from the note's start, exactly as offline, so the
live samples are the offline samples), the window's samples wait in the voice's buffer until the blocks reach them,
and a voice changes engine (operator sustain -> FDM release) at a note-off's sample.

`roll_voices` itself cannot serve: it restarts the partition at its first sample (so a chain resumed mid-note would
differ from the offline chain by up to half a sample per window start) and allocates its scratch per call.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from ..fdm_kernel import _control, _phi
from ..fdm_kernel import kernel as fdm_steps
from . import window_ops as K

_JIT = dict(fastmath=K._FM, error_model="numpy", cache=True)

FREE, OPERATOR, FDM = 0, 1, 2  # a slot's mode
HELD, CURVE, LIVE = 0, 1, 2  # a slot's pitch: constant, breakpoints (a scene's f0 curve), bend and vibrato (play)
# pp[slot] columns: the note's f0 (Hz), F_B / w, then for LIVE the pitch bend's ramp (from, to in semitones, its
# start in the note's samples), the vibrato depth's (from, to in semitones), its start, the vibrato rate (Hz), and the
# ramps' length (samples)
P_F0, P_BETA, P_B0, P_B1, P_BT, P_D0, P_D1, P_DT, P_RATE, P_RAMP = range(10)
WHY_OK, WHY_FALLBACK = 0, 1  # why[slot]: the operator left its states and the FDM finished the note


@numba.njit(**_JIT)
def trunk_basis(grid, h, corr_scale, bias, window, lin_kind, lin_d, lin_qs, dtau, n_lo, n_hi, Bq, Bp, endb, endlin,
                idx, wts):
    """One voice's window basis (rollout.NumpyOperator.window_basis) at sample spacing dtau, into Bq, Bp (k + 3, >=
    n_hi) float32 and endb (2, 2, k), endlin (2, 6) float64, with no allocation (idx (>= n_hi + 1,) and wts (4, >=
    n_hi + 1) are scratch).

    The trunk features at the offsets come from `grid` (2, k, G), the trunk evaluated at s = (i - 1) h, by the same
    cubic Lagrange interpolation `trunk_features` uses past TRUNK_GRID points (error below 1e-9 of the features,
    far under float32 rounding). Feature by feature over the samples, so each row is written in order (sample by
    sample over the features wrote 2k rows a column at a time: 6x slower). lin_kind: 0 the rotation, 1 the flow
    linearised at rest (lin_d, lin_qs), 2 none."""
    G = grid.shape[2]
    k = grid.shape[1]
    wd = math.sqrt(max(1.0 - 0.25 * lin_d * lin_d, 1e-30))
    for j in range(n_hi + 1):
        s = j * dtau / window
        u = s / h + 1.0
        i = min(max(int(math.floor(u)), 1), G - 3)
        t = u - i
        idx[j] = i - 1
        wts[0, j] = -t * (t - 1.0) * (t - 2.0) / 6.0 * s
        wts[1, j] = (t + 1.0) * (t - 1.0) * (t - 2.0) / 2.0 * s
        wts[2, j] = -(t + 1.0) * t * (t - 2.0) / 2.0 * s
        wts[3, j] = (t + 1.0) * t * (t - 1.0) / 6.0 * s
    for r in range(2):
        B = Bq if r == 0 else Bp
        c = corr_scale[r]
        for kk in range(k):
            row = grid[r, kk]
            for j in range(n_hi):
                a = idx[j]
                B[kk, j] = c * (wts[0, j] * row[a] + wts[1, j] * row[a + 1] + wts[2, j] * row[a + 2]
                                + wts[3, j] * row[a + 3])
            for e in range(2):
                jj = n_lo if e == 0 else n_hi
                a = idx[jj]
                endb[e, r, kk] = c * (wts[0, jj] * row[a] + wts[1, jj] * row[a + 1] + wts[2, jj] * row[a + 2]
                                      + wts[3, jj] * row[a + 3])
    for j in range(n_hi + 1):
        tau = j * dtau
        s = tau / window
        if lin_kind == 0:
            m11 = math.cos(tau)
            m12 = math.sin(tau)
            m21 = -m12
            m22 = m11
            kq = 0.0
            kp = 0.0
        elif lin_kind == 1:
            e = math.exp(-0.5 * lin_d * tau)
            cw = math.cos(wd * tau)
            sn = math.sin(wd * tau) / wd
            m11 = e * (cw + 0.5 * lin_d * sn)
            m12 = e * sn
            m21 = -e * sn
            m22 = e * (cw - 0.5 * lin_d * sn)
            kq = lin_qs * (1.0 - m11)
            kp = -lin_qs * m21
        else:
            m11 = 1.0
            m12 = 0.0
            m21 = 0.0
            m22 = 1.0
            kq = 0.0
            kp = 0.0
        bq = bias[0] * corr_scale[0] * s + kq
        bp = bias[1] * corr_scale[1] * s + kp
        if j < n_hi:
            Bq[k, j] = m11
            Bq[k + 1, j] = m12
            Bq[k + 2, j] = bq
            Bp[k, j] = m22
            Bp[k + 1, j] = -m21
            Bp[k + 2, j] = bp
        for e in range(2):
            if (e == 0 and j == n_lo) or (e == 1 and j == n_hi):
                endlin[e, 0] = m11
                endlin[e, 1] = m12
                endlin[e, 2] = bq
                endlin[e, 3] = bp
                endlin[e, 4] = m22
                endlin[e, 5] = -m21


@numba.njit(**_JIT)
def _ramp(a, b, t0, length, s):
    if s <= t0:
        return a
    if s >= t0 + length:
        return b
    return a + (b - a) * (s - t0) / length


@numba.njit(**_JIT)
def f0_at(v, s, pit, sr):
    """Slot v's f0 (Hz) at the note's sample s (a float): held, its breakpoints (times in s, linear between, held
    outside: controls.Curve), or the live bend and vibrato
    f0 2^((bend + depth sin(2 pi rate t)) / 12), each control a ramp from its last change."""
    pm, pp, pt, pv, npt = pit[0], pit[1], pit[2], pit[3], pit[4]
    if pm[v] == HELD:
        return pp[v, P_F0]
    if pm[v] == CURVE:
        t = s / sr
        n = npt[v]
        if t <= pt[v, 0]:
            return pv[v, 0]
        for i in range(n - 1):
            if t < pt[v, i + 1]:
                return pv[v, i] + (pv[v, i + 1] - pv[v, i]) * (t - pt[v, i]) / (pt[v, i + 1] - pt[v, i])
        return pv[v, n - 1]
    bend = _ramp(pp[v, P_B0], pp[v, P_B1], pp[v, P_BT], pp[v, P_RAMP], s)
    depth = _ramp(pp[v, P_D0], pp[v, P_D1], pp[v, P_DT], pp[v, P_RAMP], s)
    semis = bend + depth * math.sin(2.0 * math.pi * pp[v, P_RATE] * s / sr)
    return pp[v, P_F0] * 2.0 ** (semis / 12.0)


@numba.njit(**_JIT)
def _next_window(v, ops, pit, tb):
    """Start slot v's next window: its length, and for a moving pitch the window's own sample spacing: f0 at the
    window's middle (predicted with the last window's length), the window's end at the sample nearest the running
    sum of samples per window (window_end's rule, with a spw per window), the basis rebuilt when the spacing
    changed. Returns the window's length."""
    spw, n_lo, Bq, Bp, endb, endlin, win, wstart, wlen = (ops[1], ops[2], ops[3], ops[4], ops[5], ops[6], ops[11],
                                                         ops[12], ops[13])
    pm, wfrac, bdtau = pit[0], pit[5], pit[6]
    grid, hg, corr_scale, bias, window, lin_kind, lin_d, lin_qs, sr, n_max, idx, wts = tb
    win[v] += 1
    wstart[v] += wlen[v]
    if pm[v] == HELD:
        e = (win[v] + 1) * spw[v]
        wfrac[v] = e
        n = K.window_end(win[v], spw[v]) - wstart[v]
        wlen[v] = n
        return n
    f = f0_at(v, wstart[v] + 0.5 * spw[v], pit, sr)
    dtau = 2.0 * math.pi * f / sr
    s_w = window / dtau
    lo = int(math.floor(s_w))
    hi = int(math.ceil(s_w))
    if hi + 1 > n_max or lo < 1:  # a pitch beyond what the slot was sized for: held at the edge
        s_w = min(max(s_w, 1.0), n_max - 2.0)
        dtau = window / s_w
        lo = int(math.floor(s_w))
        hi = int(math.ceil(s_w))
    if dtau != bdtau[v]:
        trunk_basis(grid, hg, corr_scale, bias, window, lin_kind, lin_d, lin_qs, dtau, lo, hi, Bq[v], Bp[v], endb[v],
                    endlin[v], idx, wts)
        bdtau[v] = dtau
    spw[v] = s_w
    n_lo[v] = lo
    wfrac[v] += s_w
    n = int(math.floor(wfrac[v] + 0.5)) - wstart[v]
    wlen[v] = n
    return n


@numba.njit(**_JIT)
def _window(v, net, ops, scr, pit, tb):
    """Slot v's next window (kernels.roll_voices' body): its samples into the slot's buffer, the end state into x[v].
    Returns 0, or 1 if the end state is non-finite, 2 if it is outside the model's states (x[v] then unchanged)."""
    ff, Gw, Gb, Hw, Hb, Ow, Ob, box, mask = net
    x, spw, n_lo, Bq, Bp, endb, endlin, center, halfrange, pin, gain, win, wstart, wlen, qbuf, pbuf, op_end = ops
    h, g, u, vv_, z, hh, o = scr
    k = endb.shape[3]
    width = Hw.shape[1]
    n = _next_window(v, ops, pit, tb)
    q0 = x[v, 0]
    p0 = x[v, 1]
    K._features(q0, p0, center[v], halfrange[v], ff, pin[v], h)
    K._dense(h, Gw, Gb, g)
    for j in range(width):  # modified MLP: h = v + tanh(z) (u - v); u is kept as u - v
        t = K.tanh32(g[width + j])
        u[j] = K.tanh32(g[j]) - t
        vv_[j] = t
        hh[j] = t + K.tanh32(g[2 * width + j]) * u[j]
    for layer in range(Hw.shape[0]):
        K._dense(hh, Hw[layer], Hb[layer], z)
        for j in range(width):
            hh[j] = vv_[j] + K.tanh32(z[j]) * u[j]
    K._dense(hh, Ow, Ob, o)
    gw = gain[v]
    for j in range(2 * k):
        o[j] *= gw
    K._samples(q0, p0, o, gw, Bq[v], Bp[v], n, qbuf[v, :n], pbuf[v, :n])
    e = n - n_lo[v]
    nq, np_ = K._end_state(q0, p0, o[:k], o[k:], gw, endb[v, e], endlin[v, e])
    if not (math.isfinite(nq) and math.isfinite(np_)):
        return 1
    if not K._in_domain(nq, np_, box, mask):
        return 2
    x[v, 0] = nq
    x[v, 1] = np_
    return 0


@numba.njit(**_JIT)
def advance_to(v, target, net, ops, scr, fdm, why, pit, tb):
    """Compute slot v's windows until its buffer holds the note's sample `target` (a note-off's sample: the release
    starts from the sustain's state there). A window that leaves the model's states marks where the FDM takes over
    (op_end[v]: its last sample, as rollout._finish does offline; why[v] = WHY_FALLBACK)."""
    wstart, wlen, op_end = ops[12], ops[13], ops[16]
    while target >= wstart[v] + wlen[v] and op_end[v] < 0:
        qbuf, pbuf = ops[14], ops[15]
        lq = qbuf[v, max(wlen[v] - 1, 0)]
        lp = pbuf[v, max(wlen[v] - 1, 0)]
        bad = _window(v, net, ops, scr, pit, tb)
        if bad == 2:  # the window itself is good, its end state is not: hand over at its last sample
            op_end[v] = wstart[v] + wlen[v] - 1
            why[v] = WHY_FALLBACK
        elif bad == 1:  # non-finite samples: hand over from the last good sample, now
            qbuf[v, 0] = lq
            pbuf[v, 0] = lp
            wlen[v] = 1
            op_end[v] = wstart[v]
            why[v] = WHY_FALLBACK


@numba.njit(**_JIT)
def render(mode, pos, end, net, ops, scr, fdm, pit, tb, out, outp, off, m, amp, why):
    """Add m samples of every sounding slot to out[off:off + m] (times amp), advancing each slot.

    Per slot: mode (FREE, OPERATOR, FDM), pos the note's next sample, end the note's last sample + 1 (-1 while it is
    held). An operator slot plays its buffered window (samples wstart .. wstart + wlen of the note) and computes the
    next when the block reaches it. An FDM slot runs fdm_kernel.kernel from its state fst = (u_prev, u_cur, eta, k,
    w, a, fb) and fint = (steps done, stride), its controls the breakpoints vb_t/vb_v (nvb of them) and fb_t/fb_v,
    into the scratch su, se. A slot reaching `end` is freed. outp (empty, or as long as out): the velocities p summed
    likewise (an offline render of one scene wants both)."""
    want_p = outp.shape[0] > 0
    qbuf, pbuf, wstart, wlen, op_end = ops[14], ops[15], ops[12], ops[13], ops[16]
    fst, fint, vb_t, vb_v, nvb, fb_t, fb_v, su, se = fdm
    for v in range(mode.shape[0]):
        j = 0
        while j < m and mode[v] != FREE:
            if end[v] >= 0 and pos[v] >= end[v]:
                mode[v] = FREE
                break
            lim = m - j
            if end[v] >= 0:
                lim = min(lim, end[v] - pos[v])
            if mode[v] == OPERATOR:
                if op_end[v] >= 0 and pos[v] >= op_end[v]:  # the FDM takes over here, with the bow the slot holds
                    a = pos[v] - wstart[v]
                    to_fdm(v, float(qbuf[v, a]), float(pbuf[v, a]), fdm, pit, tb[8], pos[v])
                    mode[v] = FDM
                    continue
                advance_to(v, pos[v], net, ops, scr, fdm, why, pit, tb)
                stop = wstart[v] + wlen[v]
                if op_end[v] >= 0:
                    stop = min(stop, op_end[v])
                n = min(lim, stop - pos[v])
                a = pos[v] - wstart[v]
                for i in range(n):
                    out[off + j + i] += amp * qbuf[v, a + i]
                if want_p:
                    for i in range(n):
                        outp[off + j + i] += amp * pbuf[v, a + i]
                pos[v] += n
                j += n
            else:
                n = min(lim, su.shape[1])
                if pit[0][v] != HELD:  # w is linear over a run: short runs follow a vibrato (64: within 0.001 cent)
                    n = min(n, 64)
                stride = fint[v, 1]
                k = fst[v, 3]
                nw = 1
                w0 = fst[v, 4]
                w1 = w0
                if pit[0][v] != HELD:  # the pitch moves: w and F_B = beta w linear over this run (<= one block)
                    w0 = 2.0 * math.pi * f0_at(v, float(pos[v]), pit, tb[8])
                    w1 = 2.0 * math.pi * f0_at(v, float(pos[v] + n), pit, tb[8])
                    t0 = fint[v, 0] * k
                    wt, wv = pit[7], pit[8]
                    wt[v, 0] = t0
                    wt[v, 1] = t0 + n * stride * k
                    wv[v, 0] = w0
                    wv[v, 1] = w1
                    fb_t[v, 0] = t0
                    fb_t[v, 1] = wt[v, 1]
                    fb_v[v, 0] = pit[1][v, P_BETA] * w0
                    fb_v[v, 1] = pit[1][v, P_BETA] * w1
                    nw = 2
                else:
                    wt, wv = pit[7], pit[8]
                    wt[v, 0] = 0.0
                    wv[v, 0] = w0
                up, uc, eta = fdm_steps(fst[v, 0], fst[v, 1], fst[v, 2], fint[v, 0], n, stride, k, wt[v, :nw],
                                        wv[v, :nw], fb_t[v, :nw], fb_v[v, :nw], vb_t[v, :nvb[v]], vb_v[v, :nvb[v]],
                                        fst[v, 5], su[v, :n], se[v, :n])
                fst[v, 0] = up
                fst[v, 1] = uc
                fst[v, 2] = eta
                fint[v, 0] += n * stride
                for i in range(n):
                    w = w0 + (w1 - w0) * i / n
                    out[off + j + i] += amp * (w * su[v, i])
                if want_p:  # p = eta + v_B at the sample's step (fdm.render_fdm)
                    ivb = 0
                    for i in range(n):
                        vb, ivb = _control(vb_t[v, :nvb[v]], vb_v[v, :nvb[v]], (fint[v, 0] - (n - i) * stride) * k,
                                           ivb)
                        outp[off + j + i] += amp * (se[v, i] + vb)
                pos[v] += n
                j += n


@numba.njit(**_JIT)
def to_fdm(v, q0, p0, fdm, pit, sr, s):
    """Slot v goes on with the FDM from the state (q0, p0) at the note's sample s, the FDM's time restarting at 0
    there (the caller has set its bow breakpoints vb_t/vb_v and fst[v, 3:7] = k, w, a, fb, fint[v, 1] = stride; a
    moving pitch takes w and F_B = beta w at s): fdm.taylor_start, the scheme's start from a state."""
    fst, fint, vb_t, vb_v = fdm[0], fdm[1], fdm[2], fdm[3]
    k = fst[v, 3]
    w = fst[v, 4]
    fb = fst[v, 6]
    if pit[0][v] != HELD:
        w = 2.0 * math.pi * f0_at(v, float(s), pit, sr)
        fb = pit[1][v, P_BETA] * w
    a = fst[v, 5]
    vb0 = vb_v[v, 0]
    u0 = q0 / w
    fst[v, 0] = u0 - k * p0 - 0.5 * k * k * (w * w * u0 + fb * _phi(p0 - vb0, a))
    fst[v, 1] = u0
    fst[v, 2] = p0 - vb0
    fint[v, 0] = 0


@numba.njit(**_JIT)
def pick_slot(mode, end, pos, start):
    """A free slot; else the one to steal: the releasing voice nearest its end, else the oldest."""
    best = -1
    for v in range(mode.shape[0]):
        if mode[v] == FREE:
            return v
    for v in range(mode.shape[0]):
        if end[v] >= 0 and (best < 0 or end[v] - pos[v] < end[best] - pos[best]):
            best = v
    if best >= 0:
        return best
    best = 0
    for v in range(mode.shape[0]):
        if start[v] < start[best]:
            best = v
    return best


@numba.njit(**_JIT)
def dc_block(x, n, r, state, y):
    """y[:n] = the causal DC blocker y[i] = x[i] - x[i - 1] + r y[i - 1] of x[:n], its memory in state (x, y)."""
    xp = state[0]
    yp = state[1]
    for i in range(n):
        yi = x[i] - xp + r * yp
        xp = x[i]
        yp = yi
        y[i] = yi
    state[0] = xp
    state[1] = yp
