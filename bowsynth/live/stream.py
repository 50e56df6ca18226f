"""The streaming engine: MIDI events in, blocks of audio out, the same notes `bowsynth score` renders from a MIDI file.

    from bowsynth.live import Stream
    s = Stream(sample_rate=44100, block=512, voices=16)        # everything prepared here (seconds)
    out = s.process(512, [(0, b"\\x90\\x45\\x40"), (300, b"\\x80\\x45\\x00")])   # float32 view, 512 samples

A note is what `score` makes of a MIDI note (`score.load_midi_score`): its bow from the velocity and the channel's
CC2 / CC11 at the note-on (`midi.bow_beta`, `midi.bow_vb`, the one mapping), tuned with the truth's sounding ratio,
its sustain rolled out by the operator from rest starting at the note-on's frame, window after window exactly as
offline (window w at the sample nearest w T from the note's start), and at the note-off's frame the bow stop
(v_B -> 0 over `release` s) and tail by the FDM from the sustain's state there. So each live note is the offline note
sample for sample (up to float32 rounding: offline may run the numpy loop), and the output is their sum times `amp`
through a causal DC blocker (offline removes the DC with a zero-phase filter over the whole file).

Real time: `__init__` loads the model, evaluates the trunk on a fine grid, compiles (or loads from numba's cache) the
loops, measures or reads every velocity's sounding ratio and allocates every buffer; `process` then creates no numpy
array, imports nothing, loads nothing and compiles nothing: per event it writes a few numbers into a voice's slot and
builds the voice's window basis by interpolation in place (`voices.trunk_basis`), and renders with `voices.render`.

What differs from offline, by design:
- a controller changed while a note sounds acts on the notes struck after it (the file reader follows it within the
  note, with a 5 ms ramp, and tunes the note at the bow's median over the note, which a live note cannot know);
- a note struck with CC2 / CC11 away from neutral is tuned with a ratio interpolated on a grid of measured bows
  (the 127 velocities at neutral controllers are measured exactly before activation);
- a note the model does not cover (its bow outside the model's box, its pitch too high for one sample per window) is
  played whole by the FDM, as `score --fallback fdm` does;
- with every voice busy a new note takes the voice nearest its end (releasing first, then the oldest): `stolen`;
- note-ons beyond what the block's time allows (`busy_fraction` of the period spent) are dropped and counted, so a
  flood of 10,000 notes a second keeps the engine on time; malformed MIDI bytes are dropped and counted.
"""

from __future__ import annotations

import math
import time

import numpy as np

from .. import midi as M
from .. import physics
from ..errors import UsageError
from ..npnet import PARAM_SPAN
from ..pitch import midi_to_hz
from ..score import stop_tail
from . import voices as V

DC_HZ = 5.0  # the causal DC blocker's corner: a bowed note's static offset is not sound (wav.remove_dc: 5 Hz too)
AMP = 0.25  # output = AMP x the sum of the notes' q = w u (m/s): a note's q peaks near 0.3-0.6
TRUNK_POINTS = 8192  # the trunk grid: spacing ~2.4e-4 of a window, interpolation error ~1e-9 (rollout.TRUNK_GRID)
TIMES = 1 << 16
# the tuning grid for bows off the velocity table: F_B / w over the velocities' span (0.040..0.637) and a little
# more, v_B from where a note barely speaks to the fastest velocity's bow; 9 x 8 ratios, measured once (disk-cached)
GRID_BETA, GRID_VB, GRID_N = (0.03, 0.8), (0.1, 0.25), (9, 8)
DENSE = (512, 256)  # the spline through them, tabulated  # callback durations kept for the percentiles (the last ~6 minutes at 512 frames)


class Stream:
    """Events in, blocks out; see the module docstring. engine: 'operator' or 'fdm'. model: a model, path or name
    (default: the validated model covering the most velocities). release: the bow stop's length (s)."""

    def __init__(self, sample_rate: int = 44100, block: int = 512, voices: int = 16, engine: str = "operator",
                 model=None, a4: float = 440.0, release: float | None = None, amp: float = AMP,
                 busy_fraction: float = 0.5, dc_hz: float = DC_HZ):
        from ..pitch import check_a4
        from ..score import RELEASE

        if isinstance(voices, bool) or not isinstance(voices, int) or voices < 1:
            raise UsageError(f"--voices must be a whole number >= 1, got {voices!r}")
        if engine not in ("operator", "fdm"):
            raise UsageError(f"engine must be operator or fdm, got {engine!r}")
        if block < 1:
            raise UsageError(f"block must be >= 1 frame, got {block}")
        self.sample_rate, self.block, self.n_voices, self.engine = int(sample_rate), int(block), voices, engine
        self.a4 = check_a4(a4)
        self.release = RELEASE if release is None else float(release)
        self.amp, self.busy_fraction = float(amp), float(busy_fraction)
        self.a = 100.0  # the friction shape every MIDI note plays (Scene's default, as the file reader's notes)
        self._prepare_tuning()
        self.model = None
        if engine == "operator":
            self._prepare_operator(model)
        self._allocate(dc_hz)
        self._warm()

    # --- preparation (before activation) ----------------------------------------------------------------------

    def _prepare_tuning(self) -> None:
        """The sounding ratio of every velocity at neutral controllers (disk-cached; ~0.07 s each the first time)."""
        from ..pitch import SilentNoteError, sounding_ratio

        self.v_beta = np.array([M.bow_beta(v) for v in range(128)])
        self.v_vb = np.array([M.bow_vb(v) for v in range(128)])
        self.v_ratio = np.full(128, np.nan)
        for v in range(1, 128):
            try:
                self.v_ratio[v] = sounding_ratio(self.v_beta[v], self.v_vb[v], self.a).r
            except SilentNoteError:
                pass  # a velocity whose note does not speak stays NaN: its notes are dropped (`silent`)
        # bows away from the table (CC2 / CC11 moved): the ratio interpolated on a grid over the bows the velocities
        # and controllers reach (docs/live.md gives its error); outside the grid, held at its edge
        self.g_logb = np.linspace(math.log(GRID_BETA[0]), math.log(GRID_BETA[1]), GRID_N[0])
        self.g_vb = np.linspace(GRID_VB[0], GRID_VB[1], GRID_N[1])
        self.g_ratio = np.full(GRID_N, np.nan)
        for i, lb in enumerate(self.g_logb):
            for j, vb in enumerate(self.g_vb):
                try:
                    self.g_ratio[i, j] = sounding_ratio(float(math.exp(lb)), float(vb), self.a).r
                except SilentNoteError:
                    pass
        # bicubic through the measured points (bilinear was 4-7 cents off between them; this 0.01-0.22), sampled
        # densely here so that the callback interpolates bilinearly in a table (no scipy call there)
        from scipy.interpolate import RectBivariateSpline

        r = self.g_ratio
        if np.isnan(r).any():  # a silent corner: filled from its neighbours along v_B (it is never played)
            for i in range(r.shape[0]):
                ok = ~np.isnan(r[i])
                r[i] = np.interp(self.g_vb, self.g_vb[ok], r[i][ok]) if ok.any() else np.nanmean(r)
        spline = RectBivariateSpline(self.g_logb, self.g_vb, r, kx=3, ky=3)
        self.g_logb = np.linspace(self.g_logb[0], self.g_logb[-1], DENSE[0])
        self.g_vb = np.linspace(self.g_vb[0], self.g_vb[-1], DENSE[1])
        self.g_ratio = spline(self.g_logb, self.g_vb)

    def _prepare_operator(self, model) -> None:
        from ..npnet import trunk_features
        from ..rollout import _operator, as_model, available_models

        if model is None:
            model = self._default_model(available_models())
        m = self.model = as_model(model)
        op = self.op = _operator(m)
        d = m.domain
        self.covered = np.zeros(128, bool)
        for v in range(1, 128):
            self.covered[v] = bool(d.box_contains(self.v_beta[v], self.v_vb[v])) and math.isclose(d.a, self.a,
                                                                                                 rel_tol=1e-9)
        # the longest window any playable note needs: the lowest MIDI note (12) at the lowest f0 (r < 1 raises f0)
        self.n_max = int(math.ceil(op.window / physics.dtau(midi_to_hz(12, self.a4), self.sample_rate))) + 2
        cfg = op.cfg
        self.s_max = 2.0  # window fractions up to n_hi / spw < 1 + 1 / spw <= 2 (a window holds at least a sample)
        self.h_grid = self.s_max / (TRUNK_POINTS - 3)
        self.grid = np.ascontiguousarray(trunk_features(m.weights, cfg, (np.arange(TRUNK_POINTS) - 1.0)
                                                        * self.h_grid))
        self.lin_kind = 2 if not cfg.linear_flow else (0 if op.lin is None else 1)
        self.lin_d, self.lin_qs = op.lin if op.lin is not None else (0.0, 0.0)
        self.k = cfg.k
        self.n_par = cfg.params
        box = np.array([d.q_lo, d.q_hi, d.p_lo, d.p_hi])
        self.net = (op.ff, *op.weights, box, np.ascontiguousarray(d.mask))

    def _default_model(self, models):
        """The validated model that covers the most velocities at neutral controllers (ties: lowest validation
        NMSE), so that one model plays the keyboard; the rest of the velocities play the FDM."""
        from ..errors import DomainError

        best, score = None, (-1, 0.0)
        for m in models:
            if m.failure is not None or not math.isclose(m.domain.a, self.a, rel_tol=1e-9):
                continue
            n = int(np.sum(m.domain.box_contains(self.v_beta[1:], self.v_vb[1:])))
            s = (n, -float((m.meta.validation or {}).get("nmse", math.inf)))
            if n and s > score:
                best, score = m, s
        if best is None:
            raise DomainError("no validated operator model plays any MIDI velocity; play with --method fdm or train "
                              "one (bowsynth train --f0 100 --fb 9.42:251.4 --vb 0.05:0.3)")
        return best

    def _allocate(self, dc_hz: float) -> None:
        nv, bl = self.n_voices, self.block
        self.mode = np.zeros(nv, np.int64)
        self.pos = np.zeros(nv, np.int64)
        self.end = np.full(nv, -1, np.int64)
        self.start = np.zeros(nv, np.int64)  # the frame each slot's note started (stealing takes the oldest)
        self.key = np.full(nv, -1, np.int64)  # channel * 128 + note of the slot's note, -1 once released
        self.vb_hold = np.zeros(nv)
        self.why = np.zeros(nv, np.int64)
        self.sounding = np.full(16 * 128, -1, np.int64)  # slot of each (channel, note) held
        self.cc = np.zeros((16, 128), np.int64)  # each channel's controllers, neutral until a message moves them
        self.cc[:, M.CC_PRESSURE] = M.NEUTRAL[M.CC_PRESSURE]
        self.cc[:, M.CC_EXPRESSION] = M.NEUTRAL[M.CC_EXPRESSION]
        if self.engine == "operator":
            k, n = self.k, self.n_max
            width = self.op.cfg.width
            self.ops = (np.zeros((nv, 2)), np.zeros(nv), np.zeros(nv, np.int64),
                        np.zeros((nv, k + 3, n), np.float32), np.zeros((nv, k + 3, n), np.float32),
                        np.zeros((nv, 2, 2, k)), np.zeros((nv, 2, 6)), np.zeros((nv, 2)), np.ones((nv, 2)),
                        np.zeros((nv, self.n_par)), np.ones(nv), np.zeros(nv, np.int64), np.zeros(nv, np.int64),
                        np.zeros(nv, np.int64), np.zeros((nv, n), np.float32), np.zeros((nv, n), np.float32),
                        np.full(nv, -1, np.int64))
            self.scr = (np.zeros(self.op.ff.shape[1] * 2, np.float32), np.zeros(3 * width, np.float32),
                        np.zeros(width, np.float32), np.zeros(width, np.float32), np.zeros(width, np.float32),
                        np.zeros(width, np.float32), np.zeros(2 * k, np.float32))
            # per velocity (neutral controllers): the branch's bow inputs, the correction's gain, the state scaling
            # (NumpyOperator.window_inputs: the offline rollout's own code)
            pin, gain, c, h = self.op.window_inputs(np.stack([self.v_beta, self.v_vb], 1)[None])
            self.v_pin, self.v_gain, self.v_center, self.v_half = pin[0], gain[0], c[0], h[0]
        else:
            self.ops = (np.zeros((1, 2)), np.zeros(1), np.zeros(1, np.int64), np.zeros((1, 3, 1), np.float32),
                        np.zeros((1, 3, 1), np.float32), np.zeros((1, 2, 2, 0)), np.zeros((1, 2, 6)), np.zeros((1, 2)),
                        np.ones((1, 2)), np.zeros((1, 0)), np.ones(1), np.zeros(1, np.int64), np.zeros(1, np.int64),
                        np.zeros(1, np.int64), np.zeros((1, 1), np.float32), np.zeros((1, 1), np.float32),
                        np.full(1, -1, np.int64))
            self.scr = tuple(np.zeros(1, np.float32) for _ in range(7))
            self.net = (np.zeros((2, 1)), np.zeros((2, 3), np.float32), np.zeros(3, np.float32),
                        np.zeros((0, 1, 1), np.float32), np.zeros((0, 1), np.float32), np.zeros((1, 0), np.float32),
                        np.zeros(0, np.float32), np.zeros(4), np.ones((1, 1), np.bool_))
        self.fdm = (np.zeros((nv, 7)), np.zeros((nv, 2), np.int64), np.zeros((nv, 3)), np.zeros((nv, 3)),
                    np.zeros(nv, np.int64), np.zeros((nv, 1)), np.zeros((nv, 1)), np.zeros((nv, bl)),
                    np.zeros((nv, bl)))
        self.mix = np.zeros(bl)
        self.out = np.zeros(bl, np.float32)
        self.dc_state = np.zeros(2)
        self.dc_r = 1.0 - 2.0 * math.pi * dc_hz / self.sample_rate
        self.frame = 0  # frames processed since the start
        self.times = np.zeros(TIMES)
        self.n_times = 0
        self.counts = dict(notes=0, dropped_bytes=0, dropped_busy=0, stolen=0, fdm_notes=0, fallbacks=0, silent=0,
                           out_of_range=0, ignored=0, zero_length=0)

    def _warm(self) -> None:
        """Compile (or load from numba's cache) and run every path once, then reset: the first note after
        activation costs what every later note costs."""
        on = [(0, bytes((0x90, 69, v))) for v in (64, 100)] + [(1, bytes((0x90, 45, 64)))]
        self.process(self.block, on)
        self.process(self.block, [(0, bytes((0x80, 69, 0))), (5, bytes((0x80, 45, 0)))])
        for _ in range(int(0.2 * self.sample_rate / self.block) + 2):
            self.process(self.block, [])
        self.reset()

    def reset(self) -> None:
        """Silence: every voice freed, counters and timings cleared, time back to frame 0."""
        self.mode[:] = V.FREE
        self.end[:] = -1
        self.key[:] = -1
        self.sounding[:] = -1
        self.ops[16][:] = -1
        self.dc_state[:] = 0.0
        self.frame = 0
        self.n_times = 0
        for k in self.counts:
            self.counts[k] = 0

    # --- the audio side ---------------------------------------------------------------------------------------

    def process(self, n: int, events=()) -> np.ndarray:
        """Render the next n frames (n <= block) with `events`, (frame offset in this block, MIDI bytes) in time
        order, applied at their frames. Returns a float32 view of the output (valid until the next call)."""
        t0 = time.perf_counter()
        self._busy_until = t0 + self.busy_fraction * n / self.sample_rate
        mix = self.mix
        mix[:n] = 0.0
        at = 0
        for off, data in events:
            off = min(max(int(off), at), n)
            if off > at:
                self._render(at, off - at)
                at = off
            self._event(off, data)
        if at < n:
            self._render(at, n - at)
        V.dc_block(mix, n, self.dc_r, self.dc_state, self.out)
        self.frame += n
        self.times[self.n_times % TIMES] = time.perf_counter() - t0
        self.n_times += 1
        return self.out[:n]

    def _render(self, off: int, m: int) -> None:
        V.render(self.mode, self.pos, self.end, self.net, self.ops, self.scr, self.fdm, self.mix, off, m, self.amp,
                 self.why)

    def _event(self, off: int, data) -> None:
        """One MIDI message at frame `off` of the block: note on/off, CC 2/11/123; anything malformed is dropped."""
        n = len(data)
        if n == 0:
            self.counts["dropped_bytes"] += 1
            return
        status = data[0]
        if status >= 0xF0:  # system messages (sysex, clock, ...): not for a synthesizer voice
            self.counts["ignored"] += 1
            return
        if status < 0x80 or any(b >= 0x80 for b in data[1:n]):
            self.counts["dropped_bytes"] += 1
            return
        kind, ch = status & 0xF0, status & 0x0F
        if kind in (0x80, 0x90, 0xB0, 0xE0) and n != 3:
            self.counts["dropped_bytes"] += 1
            return
        if kind == 0x90 and data[2] > 0:
            self._note_on(off, ch, data[1], data[2])
        elif kind == 0x80 or kind == 0x90:
            slot = self.sounding[ch * 128 + data[1]]
            if slot >= 0:
                self._note_off(slot)
        elif kind == 0xB0 and data[1] in (120, 123):  # all sound off / all notes off: release the channel's notes
            for slot in range(self.n_voices):
                if self.key[slot] >= 0 and self.key[slot] // 128 == ch:
                    self._note_off(slot)
        elif kind == 0xB0 and data[1] in (M.CC_PRESSURE, M.CC_EXPRESSION):
            self.cc[ch, data[1]] = data[2]
        else:
            self.counts["ignored"] += 1

    def _note_on(self, off: int, ch: int, note: int, vel: int) -> None:
        if time.perf_counter() > self._busy_until:
            self.counts["dropped_busy"] += 1
            return
        if not 12 <= note <= 119:  # the file reader refuses them (C0..B8)
            self.counts["out_of_range"] += 1
            return
        key = ch * 128 + note
        if self.sounding[key] >= 0:  # a retrigger: the sounding one ends here (as the file reader does)
            self._note_off(self.sounding[key])
        c2, c11 = self.cc[ch, M.CC_PRESSURE], self.cc[ch, M.CC_EXPRESSION]
        neutral = c2 == M.NEUTRAL[M.CC_PRESSURE] and c11 == M.NEUTRAL[M.CC_EXPRESSION]
        beta = self.v_beta[vel] if neutral else M.bow_beta(vel, c2)
        vb = self.v_vb[vel] if neutral else M.bow_vb(vel, c11)
        ratio = self.v_ratio[vel] if neutral else self._grid_ratio(beta, vb)
        if not ratio == ratio or vb <= 0 or beta <= 0:  # NaN: a silent bow
            self.counts["silent"] += 1
            return
        slot = self._free_slot()
        f0 = midi_to_hz(note, self.a4) / ratio
        w = physics.omega(f0)
        fb = beta * w
        sr = self.sample_rate
        fst, fint, vb_t, vb_v, nvb, fb_t, fb_v = self.fdm[:7]
        stride = physics.min_oversample(fb, self.a, sr, f0)
        fst[slot, 3], fst[slot, 4], fst[slot, 5], fst[slot, 6] = 1.0 / (sr * stride), w, self.a, fb
        fint[slot, 1] = stride
        fb_t[slot, 0], fb_v[slot, 0] = 0.0, fb
        vb_t[slot, 0], vb_v[slot, 0], nvb[slot] = 0.0, vb, 1
        self.pos[slot], self.end[slot], self.start[slot] = 0, -1, self.frame + off
        self.key[slot], self.vb_hold[slot], self.why[slot] = key, vb, V.WHY_OK
        self.sounding[key] = slot
        self.counts["notes"] += 1
        if self.engine == "operator" and self._operator_note(slot, vel, neutral, beta, vb, f0):
            return
        if self.engine == "operator":
            self.counts["fdm_notes"] += 1
        V.to_fdm(slot, 0.0, 0.0, self.fdm)  # the whole note by the FDM, from rest (fdm.render_fdm's start)
        self.mode[slot] = V.FDM

    def _operator_note(self, slot, vel, neutral, beta, vb, f0) -> bool:
        """Set the slot up for the operator (False: the model does not play this note)."""
        if not (self.covered[vel] if neutral else self._plays(beta, vb)):
            return False
        dtau = physics.dtau(f0, self.sample_rate)
        spw = self.op.samples_per_window(dtau)
        n_lo, n_hi = math.floor(spw), math.ceil(spw)
        if n_lo < 1 or n_hi + 1 > self.n_max:
            return False
        x, spw_a, nlo_a, Bq, Bp, endb, endlin, center, half, pin, gain, win, wstart, wlen = self.ops[:14]
        if neutral:
            pin[slot], gain[slot], center[slot], half[slot] = (self.v_pin[vel], self.v_gain[vel],
                                                                self.v_center[vel], self.v_half[vel])
        else:
            self._bow_inputs(slot, beta, vb)
        V.trunk_basis(self.grid, self.h_grid, self.op.corr_scale, self.op.bias, self.op.window, self.lin_kind,
                      self.lin_d, self.lin_qs, dtau, n_lo, n_hi, Bq[slot], Bp[slot], endb[slot], endlin[slot])
        x[slot, 0], x[slot, 1] = 0.0, 0.0
        spw_a[slot], nlo_a[slot], win[slot], wstart[slot], wlen[slot] = spw, n_lo, -1, 0, 0
        self.ops[16][slot] = -1
        self.mode[slot] = V.OPERATOR
        return True

    def _bow_inputs(self, slot, beta, vb) -> None:
        """A bow away from the velocity table (CC2 / CC11 moved): npnet's bow inputs in scalar arithmetic
        (param_inputs, gain, state_scaling), written into the slot."""
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

    def _grid_ratio(self, beta: float, vb: float) -> float:
        """The sounding ratio at a bow off the velocity table: the grid's spline, bilinear in its dense table."""
        gb, gv = self.g_logb, self.g_vb
        x = min(max((math.log(beta) - gb[0]) / (gb[1] - gb[0]), 0.0), len(gb) - 1.0)
        y = min(max((vb - gv[0]) / (gv[1] - gv[0]), 0.0), len(gv) - 1.0)
        i, j = min(int(x), len(gb) - 2), min(int(y), len(gv) - 2)
        fx, fy = x - i, y - j
        r = self.g_ratio
        return float((1 - fx) * ((1 - fy) * r[i, j] + fy * r[i, j + 1]) + fx * ((1 - fy) * r[i + 1, j]
                                                                                 + fy * r[i + 1, j + 1]))

    def _plays(self, beta: float, vb: float) -> bool:
        """Does the model play this bow (Domain.box_contains for one bow, in scalars)? A point model plays only
        the velocities the table found it covers."""
        d = self.model.domain
        if d.box is None:
            return False
        b0, b1, v0, v1 = d.box
        return (b0 <= beta <= b1 or (d.plays_below and 0.0 <= beta <= b0)) and v0 <= vb <= v1

    def _free_slot(self) -> int:
        slot = V.pick_slot(self.mode, self.end, self.pos, self.start)
        if self.mode[slot] == V.FREE:
            return slot
        # stolen: the releasing voice nearest its end, else the oldest held one
        self.counts["stolen"] += 1
        if self.key[slot] >= 0:
            self.sounding[self.key[slot]] = -1
        self.key[slot] = -1
        self.mode[slot] = V.FREE
        return slot

    def _note_off(self, slot: int) -> None:
        """The bow stop from the slot's next sample: by the FDM from the sustain's state there (operator), or the
        FDM's own bow following v_B -> 0 (a note the FDM plays whole)."""
        key = self.key[slot]
        if key >= 0:
            self.sounding[key] = -1
        self.key[slot] = -1
        h = int(self.pos[slot])
        if h == 0:  # a note of zero length: the file reader drops it
            self.mode[slot] = V.FREE
            self.counts["zero_length"] += 1
            return
        fst, fint, vb_t, vb_v, nvb = self.fdm[:5]
        vb, rel = self.vb_hold[slot], self.release
        sr = self.sample_rate
        f0 = fst[slot, 4] / (2.0 * math.pi)
        total = int(round((h / sr + rel + stop_tail(fst[slot, 6], f0, self.a)) * sr))
        if self.mode[slot] == V.OPERATOR and self.ops[16][slot] < 0:
            V.advance_to(slot, h, self.net, self.ops, self.scr, self.fdm, self.why)
        if self.mode[slot] == V.OPERATOR and (self.ops[16][slot] < 0 or h < self.ops[16][slot]):
            a = h - self.ops[12][slot]
            q0, p0 = float(self.ops[14][slot, a]), float(self.ops[15][slot, a])
            vb_t[slot, 0], vb_t[slot, 1], vb_v[slot, 0], vb_v[slot, 1], nvb[slot] = 0.0, rel, vb, 0.0, 2
            V.to_fdm(slot, q0, p0, self.fdm)
            self.mode[slot] = V.FDM
        else:  # the FDM plays on; its bow falls from its own time now (render_fdm of the note's v_B curve)
            t = fint[slot, 0] * fst[slot, 3]
            vb_t[slot, 0], vb_t[slot, 1], vb_t[slot, 2] = 0.0, t, t + rel
            vb_v[slot, 0], vb_v[slot, 1], vb_v[slot, 2], nvb[slot] = vb, vb, 0.0, 3
            if self.mode[slot] == V.OPERATOR:  # handing over mid-release is rare: let the handover happen first
                pass
        self.end[slot] = total

    # --- what it did ------------------------------------------------------------------------------------------

    def voices_sounding(self) -> int:
        return int(np.count_nonzero(self.mode != V.FREE))

    def callback_times(self) -> np.ndarray:
        """The durations (s) of the last process() calls."""
        return self.times[:min(self.n_times, TIMES)].copy()
