"""A bank of voice slots that play block by block (`voices`; the loop is the compiled core's `_core.Voices`, which
references these arrays): every array they need, allocated once, and the few Python steps that set a slot up (a
note from rest, its release, its bow's inputs). `bowsynth.live.Stream` drives one
from MIDI; `curve.render_curve` plays one scene with a pitch curve through it."""

from __future__ import annotations

import math

import numpy as np

from ... import physics
from ... import compiled as core
from . import voices as V
from .basis import TRUNK_H, TRUNK_POINTS, lined, numpy_operator, trunk_grid, whole_lines
from .npnet import PARAM_SPAN
from .onset import uses_rest_flow
from .windows import locked_window

CURVE_POINTS = 4096  # breakpoints a slot's pitch curve may hold (render_curve)


def _resident(arrays) -> None:
    """Write one byte of every memory page of each array (its own value), so that the pages are the process's before
    any callback: np.zeros maps its pages at their first write, and a slot's first note then paid for ~2 MB of page
    faults inside the audio callback (measured: a 32-note chord took 93 ms in a fresh Stream, 2.4 ms once every slot
    had played, so the chord was deferred over 10 blocks)."""
    for a in arrays:
        b = a.reshape(-1).view(np.uint8)
        b[::4096] = b[::4096].copy()


class VoiceBank:
    """`voices` slots at `sample_rate`, rendering up to `block` frames a call. engine 'operator' (model: an
    OperatorModel) or 'fdm'. lowest_f0: the lowest pitch a slot must hold a window for (it sizes the buffers)."""

    def __init__(self, sample_rate: int, block: int, voices: int, engine: str, model, lowest_f0: float):
        self.sample_rate, self.block, self.n_voices, self.engine = int(sample_rate), int(block), int(voices), engine
        self.model = model
        if engine == "operator":
            self._prepare_operator(model, lowest_f0)
        self._allocate_slots()

    def _prepare_operator(self, m, lowest_f0: float) -> None:
        op = self.op = numpy_operator(m)
        d = m.domain
        # the longest window a slot may need, at the lowest pitch it may play
        self.n_max = int(math.ceil(op.window / physics.dtau(lowest_f0, self.sample_rate))) + 2
        cfg = op.cfg
        h_grid = TRUNK_H
        # (2, k, G): each feature's values along s contiguous (trunk_basis reads them sample after sample)
        self.grid = np.ascontiguousarray(np.transpose(trunk_grid(m), (1, 2, 0)))
        lin_kind = 2 if not cfg.linear_flow else (0 if op.lin is None else 1)
        lin_d, lin_qs = op.lin if op.lin is not None else (0.0, 0.0)
        box = np.array([d.q_lo, d.q_hi, d.p_lo, d.p_hi])
        self.net = (op.ff, *op.weights, box, np.ascontiguousarray(d.mask))
        self.tb = (self.grid, h_grid, op.corr_scale, op.bias, float(op.window), int(lin_kind), float(lin_d),
                   float(lin_qs), float(self.sample_rate))

    def _allocate_slots(self) -> None:
        nv, bl = self.n_voices, self.block
        self.mode = np.zeros(nv, np.int64)
        self.pos = np.zeros(nv, np.int64)
        self.end = np.full(nv, -1, np.int64)
        self.why = np.zeros(nv, np.int64)
        if self.engine == "operator":
            # rows of whole 64-byte lines, on a line (basis.lined; a slot's notes stay within n_max)
            k, n, npar = self.op.cfg.k, whole_lines(self.n_max), self.op.cfg.params
        else:  # the FDM alone: an operator of no size, which no slot plays (the core checks the shapes all the same)
            k, n, npar = 0, 3, 0
            self.net = (np.zeros((2, 1)), np.zeros((2, 3), np.float32), np.zeros(3, np.float32),
                        np.zeros((0, 1, 1), np.float32), np.zeros((0, 1), np.float32), np.zeros((1, 0), np.float32),
                        np.zeros(0, np.float32), np.zeros(4), np.ones((1, 1), np.bool_))
            self.tb = (np.zeros((2, 0, 4)), 1.0, np.zeros(2), np.zeros(2), 1.0, 0, 0.0, 0.0, float(self.sample_rate))
        # the operator: state, samples per window, floor of it, the basis and end-state rows, the state scaling, the
        # bow inputs and gain, the window's index, first sample and length, its samples, where the FDM takes over,
        # the rest flow's row (voices.REST_COLS) and the sample the windows count from
        self.ops = (np.zeros((nv, 2)), np.zeros(nv), np.zeros(nv, np.int64), lined(np.zeros((nv, k + 3, n))),
                    lined(np.zeros((nv, k + 3, n))), np.zeros((nv, 2, 2, k)), np.zeros((nv, 2, 6)),
                    np.zeros((nv, 2)), np.ones((nv, 2)), np.zeros((nv, npar)), np.ones(nv), np.zeros(nv, np.int64),
                    np.zeros(nv, np.int64), np.zeros(nv, np.int64), np.zeros((nv, n), np.float32),
                    np.zeros((nv, n), np.float32), np.full(nv, -1, np.int64), np.zeros((nv, V.REST_COLS)),
                    np.zeros(nv, np.int64))
        # the FDM: state (u_prev, u_cur, eta, k, w, a, fb), (steps done, stride), v_B breakpoints (and how many), F_B
        # breakpoints, scratch rows
        self.fdm = (np.zeros((nv, 7)), np.zeros((nv, 2), np.int64), np.zeros((nv, 3)), np.zeros((nv, 3)),
                    np.zeros(nv, np.int64), np.zeros((nv, 2)), np.zeros((nv, 2)), np.zeros((nv, bl)),
                    np.zeros((nv, bl)))
        # pitch: mode (voices.HELD, CURVE, LIVE), parameters (voices.P_*), a curve's breakpoints, the running window
        # end, the basis's spacing, the FDM's w breakpoints
        self.pit = (np.zeros(nv, np.int64), np.zeros((nv, 10)), np.zeros((nv, CURVE_POINTS)),
                    np.zeros((nv, CURVE_POINTS)), np.ones(nv, np.int64), np.zeros(nv), np.zeros(nv), np.zeros((nv, 2)),
                    np.zeros((nv, 2)))
        self._nop = np.zeros(0)
        self._rest_in = (np.zeros(1), np.zeros(1), np.zeros(1))
        _resident((*self.ops, *self.fdm, *self.pit))
        self.voices = core.load().Voices((self.mode, self.pos, self.end, self.why), self.ops, self.net, self.tb,
                                         self.fdm, self.pit, physics.NEWTON_TOL, physics.NEWTON_MAXIT)

    def render(self, out, off: int, m: int, amp: float, outp=None) -> None:
        """Add m samples of every sounding slot, times amp, to out[off:off + m] (and their p to outp)."""
        self.voices.render(out, self._nop if outp is None else outp, off, m, amp)

    def fdm_stride(self, f0: float, beta: float, a: float, reach: float = 0.0) -> int:
        """The FDM's steps a sample for a note at f0 whose pitch may rise `reach` semitones (a live bend and
        vibrato): the stride that keeps the scheme within its bounds at the highest of them (physics.min_oversample;
        F_B / w held, so F_B rises with the pitch)."""
        top = f0 * 2.0 ** (max(reach, 0.0) / 12.0)
        return physics.min_oversample(beta * physics.omega(top), a, self.sample_rate, top)

    def start_slot(self, slot: int, f0: float, beta: float, vb: float, a: float, reach: float = 0.0) -> None:
        """A note from rest in the slot: its FDM parameters (used whole, or for the release), pitch held at f0;
        reach: the semitones its pitch may rise (fdm_stride)."""
        w = physics.omega(f0)
        fb = beta * w
        sr = self.sample_rate
        fst, fint, vb_t, vb_v, nvb, fb_t, fb_v = self.fdm[:7]
        stride = self.fdm_stride(f0, beta, a, reach)
        fst[slot, 3], fst[slot, 4], fst[slot, 5], fst[slot, 6] = 1.0 / (sr * stride), w, a, fb
        fint[slot, 1] = stride
        fb_t[slot, 0], fb_v[slot, 0] = 0.0, fb
        vb_t[slot, 0], vb_v[slot, 0], nvb[slot] = 0.0, vb, 1
        self.pos[slot], self.end[slot], self.why[slot] = 0, -1, V.WHY_OK
        pm, pp = self.pit[0], self.pit[1]
        pp[slot, V.P_F0], pp[slot, V.P_BETA] = f0, beta
        pm[slot] = V.HELD
        self.pit[5][slot] = 0.0

    def start_fdm(self, slot: int) -> None:
        """The slot's note played whole by the FDM, from rest (fdm.render_fdm's start)."""
        self.voices.to_fdm(slot, 0.0, 0.0, 0)
        self.mode[slot] = V.FDM

    def start_operator(self, slot: int, f0: float, sounding: float | None = None) -> bool:
        """The slot's note played by the operator from its state x (rest unless set), its bow inputs already in the
        slot (bow_inputs); False when no window fits the pitch. sounding: the frequency (Hz) a held pitch's note
        sounds at, its windows then locked to that period (windows.locked_window, as offline); None: the trained T."""
        dtau = physics.dtau(f0, self.sample_rate)
        window = None if sounding is None else locked_window(self.op.window, f0, sounding)
        spw = self.op.samples_per_window(dtau, window)
        n_lo, n_hi = math.floor(spw), math.ceil(spw)
        if n_lo < 1 or n_hi + 1 > self.n_max:
            return False
        x, spw_a, nlo_a = self.ops[:3]
        win, wstart, wlen = self.ops[11:14]
        self.voices.trunk_basis(slot, dtau, n_lo, n_hi)
        self.pit[6][slot] = dtau
        x[slot, 0], x[slot, 1] = 0.0, 0.0
        spw_a[slot], nlo_a[slot], win[slot], wstart[slot], wlen[slot] = spw, n_lo, -1, 0, 0
        self.ops[16][slot] = -1
        self.ops[18][slot] = 0
        self.mode[slot] = V.OPERATOR
        return True

    def start_rest(self, slot: int, beta: float, vb: float, a: float, f0: float) -> bool:
        """An operator slot (start_operator) whose state lies near its bow's rest point starts with the exact flow
        linearised there (physics.rest_flow; for the models onset.uses_rest_flow names), the operator taking over
        where the state leaves its radius; False (the slot unchanged) where it does not apply."""
        x = self.ops[0]
        if not uses_rest_flow(self.model):
            return False
        flow = physics.rest_flow(beta, vb, a, float(x[slot, 0]), float(x[slot, 1]))
        if flow is None:
            return False
        d, qs, r = flow
        rows = self.ops[17]
        dtau = physics.dtau(f0, self.sample_rate)
        d_, qs_, dt_ = self._rest_in  # preallocated: a live note-on creates no array
        d_[0], qs_[0], dt_[0] = d, qs, dtau
        core.load().rest_coefficients(d_, qs_, dt_, rows[slot:slot + 1])
        rows[slot, V.R_RADIUS], rows[slot, V.R_D], rows[slot, V.R_DTAU] = r, d, dtau
        self.mode[slot] = V.REST
        return True

    def bow_inputs(self, slot: int, beta: float, vb: float) -> None:
        """The branch's bow inputs, the correction's gain and the state scaling for one bow (npnet.param_inputs,
        gain, state_scaling), in scalar arithmetic, written into the slot."""
        w, cfg = self.model.weights, self.op.cfg
        pin, gain, center, half = self.ops[9], self.ops[10], self.ops[7], self.ops[8]
        if cfg.params:
            pc, ps = w["pcenter"], w["pscale"]
            pin[slot, 0] = max((math.log(max(beta, 1e-12)) - float(pc[0])) / float(ps[0]), -PARAM_SPAN)
            pin[slot, 1] = (vb - float(pc[1])) / float(ps[1])
        gain[slot] = beta / math.exp(float(w["pcenter"][0])) if cfg.corr_beta else 1.0
        for i in range(2):
            c, h = float(w["center"][i]), float(w["halfrange"][i])
            if cfg.bow_scaled:
                cs, hs = w["center_slope"][i], w["halfrange_slope"][i]
                c += sum(float(cs[j]) * pin[slot, j] for j in range(cfg.params))
                h *= math.exp(sum(float(hs[j]) * pin[slot, j] for j in range(cfg.params)))
            center[slot, i], half[slot, i] = c, h

    def release(self, slot: int, vb: float, release: float, tail: float) -> None:
        """The bow stop from the slot's next sample h: by the FDM from the sustain's state there (operator), or the
        FDM's own bow following v_B -> 0 over `release` s (a note the FDM plays whole); the slot ends `tail` s
        after the bow stops."""
        fst, fint, vb_t, vb_v, nvb = self.fdm[:5]
        sr = self.sample_rate
        h = int(self.pos[slot])
        total = int(round((h / sr + release + tail) * sr))
        if self.mode[slot] == V.OPERATOR and self.ops[16][slot] < 0:
            self.voices.advance_to(slot, h)
        op_here = self.mode[slot] == V.OPERATOR and (self.ops[16][slot] < 0 or h < self.ops[16][slot])
        if op_here or self.mode[slot] == V.REST:
            if op_here:
                a = h - self.ops[12][slot]
                q0, p0 = float(self.ops[14][slot, a]), float(self.ops[15][slot, a])
            else:  # still in the flow at rest: its state at sample h, in float32 as the offline sustain holds it
                q0, p0 = float(np.float32(self.ops[0][slot, 0])), float(np.float32(self.ops[0][slot, 1]))
            vb_t[slot, 0], vb_t[slot, 1], vb_v[slot, 0], vb_v[slot, 1], nvb[slot] = 0.0, release, vb, 0.0, 2
            self.voices.to_fdm(slot, q0, p0, h)
            self.mode[slot] = V.FDM
        else:  # the FDM plays on (whole, or after a hand-over): its bow falls from its own time now
            t = fint[slot, 0] * fst[slot, 3]
            vb_t[slot, 0], vb_t[slot, 1], vb_t[slot, 2] = 0.0, t, t + release
            vb_v[slot, 0], vb_v[slot, 1], vb_v[slot, 2], nvb[slot] = vb, vb, 0.0, 3
        self.end[slot] = total

    def voices_sounding(self) -> int:
        return int(np.count_nonzero(self.mode != V.FREE))
