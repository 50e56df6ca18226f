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
- note-ons beyond what the block's time allows (`busy_fraction` of the period spent) wait for the next block and start
  at its first frame, in order (`deferred`, `max_defer` frames late); past PENDING waiting they are dropped and
  counted, so a flood of 10,000 notes a second keeps the engine on time; malformed MIDI bytes are dropped, counted.
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
DENSE = (512, 256)  # the spline through them, tabulated
BEND_RANGE = 2.0  # semitones at full pitch bend (--bend-range)
VIB_HZ = 5.5  # the vibrato's rate, Hz (a violinist's is 5-7 Hz)
VIB_DEPTH = 0.5  # semitones: CC1 = 127 swings the pitch +-50 cents (midi.vibrato_depth)
PENDING = 64  # note-ons waiting for time (a 64-key chord; a flood beyond it is dropped and counted)
CURVE_POINTS = 4096  # breakpoints a scene's pitch curve may have in the offline path (render_curve)  # callback durations kept for the percentiles (the last ~6 minutes at 512 frames)


class Stream:
    """Events in, blocks out; see the module docstring. engine: 'operator' or 'fdm'. model: a model, path or name
    (default: the validated model covering the most velocities). release: the bow stop's length (s)."""

    def __init__(self, sample_rate: int = 44100, block: int = 512, voices: int = 16, engine: str = "operator",
                 model=None, a4: float = 440.0, release: float | None = None, amp: float = AMP,
                 busy_fraction: float = 0.5, dc_hz: float = DC_HZ, bend_range: float = BEND_RANGE,
                 tuning: bool = True, lowest_f0: float | None = None):
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
        if not (math.isfinite(bend_range) and 0 <= bend_range <= 24):
            raise UsageError(f"--bend-range must be 0..24 semitones, got {bend_range:g}")
        self.bend_range = float(bend_range)
        self.tuning = tuning
        if tuning:
            self._prepare_tuning()
        self.lowest_f0 = lowest_f0
        self.model = None
        if engine == "operator":
            self._prepare_operator(model)
        self._allocate(dc_hz)
        if tuning:  # an engine without the velocity table (render_curve) is driven slot by slot, not by MIDI
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
        for v in range(1, 128 if self.tuning else 1):
            self.covered[v] = bool(d.box_contains(self.v_beta[v], self.v_vb[v])) and math.isclose(d.a, self.a,
                                                                                                 rel_tol=1e-9)
        # the longest window any playable note needs: the lowest MIDI note (12) at the lowest f0 (r < 1 raises f0),
        # bent down and at the bottom of its vibrato
        lowest = midi_to_hz(12, self.a4) * 2.0 ** (-(self.bend_range + VIB_DEPTH) / 12.0)
        if self.lowest_f0 is not None:
            lowest = self.lowest_f0
        self.n_max = int(math.ceil(op.window / physics.dtau(lowest, self.sample_rate))) + 2
        cfg = op.cfg
        self.s_max = 2.0  # window fractions up to n_hi / spw < 1 + 1 / spw <= 2 (a window holds at least a sample)
        self.h_grid = self.s_max / (TRUNK_POINTS - 3)
        # (2, k, G): each feature's values along s contiguous (trunk_basis reads them sample after sample)
        self.grid = np.ascontiguousarray(np.transpose(trunk_features(m.weights, cfg, (np.arange(TRUNK_POINTS) - 1.0)
                                                                     * self.h_grid), (1, 2, 0)))
        self.lin_kind = 2 if not cfg.linear_flow else (0 if op.lin is None else 1)
        self.lin_d, self.lin_qs = op.lin if op.lin is not None else (0.0, 0.0)
        self.k = cfg.k
        self.n_par = cfg.params
        box = np.array([d.q_lo, d.q_hi, d.p_lo, d.p_hi])
        self.net = (op.ff, *op.weights, box, np.ascontiguousarray(d.mask))
        self.tb = (self.grid, self.h_grid, op.corr_scale, op.bias, float(op.window), int(self.lin_kind),
                   float(self.lin_d), float(self.lin_qs), float(self.sample_rate), int(self.n_max),
                   np.zeros(self.n_max + 1, np.int64), np.zeros((4, self.n_max + 1)))

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
            if self.tuning:
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
            self.tb = (np.zeros((2, 0, 4)), 1.0, np.zeros(2), np.zeros(2), 1.0, 0, 0.0, 0.0, float(self.sample_rate), 4,
                       np.zeros(5, np.int64), np.zeros((4, 5)))
        self.fdm = (np.zeros((nv, 7)), np.zeros((nv, 2), np.int64), np.zeros((nv, 3)), np.zeros((nv, 3)),
                    np.zeros(nv, np.int64), np.zeros((nv, 2)), np.zeros((nv, 2)), np.zeros((nv, bl)),
                    np.zeros((nv, bl)))
        # pitch: mode (voices.HELD, CURVE, LIVE), parameters (voices.P_*), a curve's breakpoints, the running window
        # end, the basis's spacing, the FDM's w breakpoints
        self.pit = (np.zeros(nv, np.int64), np.zeros((nv, 10)), np.zeros((nv, CURVE_POINTS)),
                    np.zeros((nv, CURVE_POINTS)), np.ones(nv, np.int64), np.zeros(nv), np.zeros(nv), np.zeros((nv, 2)),
                    np.zeros((nv, 2)))
        self.chan = np.zeros(nv, np.int64)  # each slot's channel (its bend and vibrato follow it through the release)
        self.bend = np.zeros(16)  # semitones, per channel
        self.depth = np.zeros(16)  # vibrato depth, semitones, per channel
        self._nop = np.zeros(0)
        self.mix = np.zeros(bl)
        self.out = np.zeros(bl, np.float32)
        self.dc_state = np.zeros(2)
        self.dc_r = 1.0 - 2.0 * math.pi * dc_hz / self.sample_rate
        self.frame = 0  # frames processed since the start
        self.times = np.zeros(TIMES)
        self.n_times = 0
        # note-ons past the block's time budget wait here (channel, note, velocity, the frame they were due) and
        # start at the next block's first frame, oldest first; a full queue drops them
        self.pending = np.zeros((PENDING, 4), np.int64)
        self.n_pending = self.head = 0
        self.counts = dict(notes=0, dropped_bytes=0, dropped_busy=0, deferred=0, max_defer=0, stolen=0, fdm_notes=0,
                           fallbacks=0, silent=0,
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
        self.n_pending = self.head = 0
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
        if self.n_pending:
            self._start_pending()
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
        V.render(self.mode, self.pos, self.end, self.net, self.ops, self.scr, self.fdm, self.pit, self.tb, self.mix,
                 self._nop, off, m, self.amp, self.why)

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
            elif self.n_pending:  # still waiting to start: it never sounds (counted as dropped)
                self._cancel_pending(ch, data[1])
        elif kind == 0xB0 and data[1] in (120, 123):  # all sound off / all notes off: release the channel's notes
            for slot in range(self.n_voices):
                if self.key[slot] >= 0 and self.key[slot] // 128 == ch:
                    self._note_off(slot)
        elif kind == 0xB0 and data[1] in (M.CC_PRESSURE, M.CC_EXPRESSION):
            self.cc[ch, data[1]] = data[2]
        elif kind == 0xE0:
            self.bend[ch] = M.bend_semitones((data[2] << 7) | data[1], self.bend_range)
            self._pitch_moved(ch)
        elif kind == 0xB0 and data[1] == M.CC_MODULATION:
            self.depth[ch] = M.vibrato_depth(data[2])
            self._pitch_moved(ch)
        else:
            self.counts["ignored"] += 1

    def _cancel_pending(self, ch: int, note: int) -> None:
        """A note-off for a note still waiting: it never sounds (marked, velocity 0; counted as dropped)."""
        q = self.pending
        for i in range(self.n_pending):
            k = (self.head + i) % PENDING
            if q[k, 0] == ch and q[k, 1] == note and q[k, 2] > 0:
                q[k, 2] = 0
                self.counts["dropped_busy"] += 1
                return

    def _start_pending(self) -> None:
        """The waiting note-ons (a ring: no array is moved), oldest first, at this block's first frame, while the
        time budget lasts."""
        q = self.pending
        while self.n_pending and time.perf_counter() <= self._busy_until:
            ch, note, vel, due = q[self.head]
            self.head = (self.head + 1) % PENDING
            self.n_pending -= 1
            if vel > 0:
                self.counts["max_defer"] = max(self.counts["max_defer"], self.frame - int(due))
                self._start_note(0, int(ch), int(note), int(vel))

    def _note_on(self, off: int, ch: int, note: int, vel: int) -> None:
        if self.n_pending or time.perf_counter() > self._busy_until:  # later, in order (a chord's top notes)
            if self.n_pending == PENDING:
                self.counts["dropped_busy"] += 1
                return
            k = (self.head + self.n_pending) % PENDING
            self.pending[k, 0], self.pending[k, 1], self.pending[k, 2], self.pending[k, 3] = (ch, note, vel,
                                                                                            self.frame + off)
            self.n_pending += 1
            self.counts["deferred"] += 1
            return
        self._start_note(off, ch, note, vel)

    def _start_note(self, off: int, ch: int, note: int, vel: int) -> None:
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
        pm, pp = self.pit[0], self.pit[1]
        self.chan[slot] = ch
        pp[slot, V.P_F0], pp[slot, V.P_BETA] = f0, beta
        pp[slot, V.P_B0] = pp[slot, V.P_B1] = self.bend[ch]
        pp[slot, V.P_D0] = pp[slot, V.P_D1] = self.depth[ch]
        pp[slot, V.P_BT] = pp[slot, V.P_DT] = 0.0
        pp[slot, V.P_RATE], pp[slot, V.P_RAMP] = VIB_HZ, M.CC_RAMP * sr
        pm[slot] = V.LIVE if (self.bend[ch] != 0 or self.depth[ch] != 0) else V.HELD
        self.pit[5][slot] = 0.0
        self.sounding[key] = slot
        self.counts["notes"] += 1
        if self.engine == "operator" and self._operator_note(slot, vel, neutral, beta, vb, f0):
            return
        if self.engine == "operator":
            self.counts["fdm_notes"] += 1
        V.to_fdm(slot, 0.0, 0.0, self.fdm, self.pit, float(sr), 0)  # the FDM from rest (fdm.render_fdm's start)
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
                      self.lin_d, self.lin_qs, dtau, n_lo, n_hi, Bq[slot], Bp[slot], endb[slot], endlin[slot],
                      self.tb[10], self.tb[11])
        self.pit[6][slot] = dtau
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

    def _pitch_moved(self, ch: int) -> None:
        """The channel's bend or vibrato depth changed: each of its notes (held or releasing) ramps to it from its
        value now (a 5 ms ramp, as the file reader's controllers) and follows it from its next window on."""
        pm, pp = self.pit[0], self.pit[1]
        for slot in range(self.n_voices):
            if self.mode[slot] == V.FREE or self.chan[slot] != ch:
                continue
            s = float(self.pos[slot])
            b = V._ramp(pp[slot, V.P_B0], pp[slot, V.P_B1], pp[slot, V.P_BT], pp[slot, V.P_RAMP], s)
            d = V._ramp(pp[slot, V.P_D0], pp[slot, V.P_D1], pp[slot, V.P_DT], pp[slot, V.P_RAMP], s)
            pp[slot, V.P_B0], pp[slot, V.P_B1], pp[slot, V.P_BT] = b, self.bend[ch], s
            pp[slot, V.P_D0], pp[slot, V.P_D1], pp[slot, V.P_DT] = d, self.depth[ch], s
            pm[slot] = V.LIVE

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
            V.advance_to(slot, h, self.net, self.ops, self.scr, self.fdm, self.why, self.pit, self.tb)
        if self.mode[slot] == V.OPERATOR and (self.ops[16][slot] < 0 or h < self.ops[16][slot]):
            a = h - self.ops[12][slot]
            q0, p0 = float(self.ops[14][slot, a]), float(self.ops[15][slot, a])
            vb_t[slot, 0], vb_t[slot, 1], vb_v[slot, 0], vb_v[slot, 1], nvb[slot] = 0.0, rel, vb, 0.0, 2
            V.to_fdm(slot, q0, p0, self.fdm, self.pit, float(sr), h)
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


def render_curve(scene, model):
    """The operator's render of a scene whose f0 follows a curve (vibrato, glissando, bend): one slot of the live
    engine, per window the window's own sample spacing (f0 at its middle), basis and end-state offsets, the same
    code `play` runs for pitch bend and CC1. F_B / w and v_B must hold (a MIDI note's bow, a score note's beta):
    else a SceneError says to render with the FDM. A window that leaves the model's states hands over to the FDM
    (following the curve) as a live note does; info['notes'] says so."""
    from ..controls import Curve, breakpoints
    from ..errors import DomainError, SceneError
    from ..fdm import check_oversample
    from ..render import Render
    from ..rollout import as_model

    t_b = np.union1d(breakpoints(scene.fb)[0], scene.f0.times)
    betas = scene.fb_at(t_b) / (2.0 * math.pi * scene.f0_at(t_b))
    if isinstance(scene.vb, Curve) or np.ptp(betas) > 1e-9 * betas.max():
        raise SceneError("the operator plays a pitch curve with F_B / w and v_B held (a bow force growing with the "
                         "pitch, beta = ...); render this scene with --method fdm")
    if len(scene.f0.points) > CURVE_POINTS:
        raise SceneError(f"a pitch curve for the operator holds at most {CURVE_POINTS} breakpoints, this one "
                         f"{len(scene.f0.points)}")
    m = as_model(model)
    beta, vb = float(betas[0]), float(scene.vb)
    if not (m.domain.box_contains(beta, vb) and math.isclose(m.domain.a, scene.a, rel_tol=1e-9)):
        raise DomainError(f"model {m.path or m.meta.name} does not play F_B / w {beta:.4g}, v_B {vb:g}, a "
                          f"{scene.a:g}; render with --method fdm")
    sr = scene.sample_rate
    st = Stream(sample_rate=sr, block=4096, voices=1, model=m, tuning=False, lowest_f0=scene.f0.lo)
    st.a = scene.a
    f0 = float(scene.f0_at(0.0))
    w0 = 2.0 * math.pi * f0
    pm, pp, pt, pv, npt = st.pit[:5]
    pm[0], npt[0] = V.CURVE, len(scene.f0.points)
    pt[0, :npt[0]], pv[0, :npt[0]] = scene.f0.times, scene.f0.values
    pp[0, V.P_F0], pp[0, V.P_BETA] = f0, beta
    st._bow_inputs(0, beta, vb)
    x, spw = st.ops[0], st.ops[1]
    x[0] = (scene.q0, scene.p0)
    spw[0] = st.op.window / physics.dtau(f0, sr)
    st.ops[11][0], st.ops[12][0], st.ops[13][0], st.ops[16][0] = -1, 0, 0, -1
    st.pit[5][0], st.pit[6][0] = 0.0, -1.0
    stride = check_oversample(scene, 1, warn=False)
    fst, fint, vb_t, vb_v, nvb = st.fdm[:5]
    fst[0, 3:7] = (1.0 / (sr * stride), w0, scene.a, beta * w0)
    fint[0, 1] = stride
    vb_t[0, 0], vb_v[0, 0], nvb[0] = 0.0, vb, 1
    st.mode[0], st.pos[0], st.end[0] = V.OPERATOR, 0, scene.n_samples
    n = scene.n_samples
    q, p = np.zeros(n), np.zeros(n)
    t0 = time.perf_counter()
    for a in range(0, n, st.block):
        k = min(st.block, n - a)
        V.render(st.mode, st.pos, st.end, st.net, st.ops, st.scr, st.fdm, st.pit, st.tb, q[a:a + k], p[a:a + k], 0,
                 k, 1.0, st.why)
    secs = time.perf_counter() - t0
    notes = ["note: the rollout left the model's trained states; finished with the FDM from there"] \
        if st.why[0] == V.WHY_FALLBACK else []
    return Render(scene, np.arange(n) / sr, q.astype(np.float32), p.astype(np.float32),
                  method="operator" + ("+fdm" if notes else ""), seconds=secs,
                  info={"model_id": m.id, "model_path": str(m.path) if m.path else None, "notes": notes,
                        "loop": "live per-window pitch"})
