"""The streaming engine (`Stream`): MIDI events in, blocks of audio out, the same notes `bowsynth score` renders
from a MIDI file; what `bowsynth play` runs inside its JACK client (`bowsynth.live.jack_client`)."""

from __future__ import annotations

import math
import time

import numpy as np

from ..engines.operator import voices as V
from ..engines.operator.bank import VoiceBank
from ..engines.operator.grid import needs_whole_windows
from ..engines.operator.windows import Lock, lock_more
from ..errors import UsageError
from ..music import midi as M
from ..music.note import RELEASE, stop_tail
from ..music.notes import check_a4, midi_to_hz
from .budget import BUDGET, Budgeted, VoiceCosts
from .tables import Tuning

DC_HZ = 5.0  # the causal DC blocker's corner: a bowed note's static offset is not sound (io.audio.remove_dc: 5 Hz)
AMP = 0.25  # output = AMP x the sum of the notes' q = w u (m/s): a note's q peaks near 0.3-0.6
TIMES = 1 << 16  # callback durations kept for the percentiles (the last ~6 minutes at 512 frames)
PENDING = 64  # note-ons waiting for time (a 64-key chord; a flood beyond it is dropped and counted)


class Stream(Budgeted, VoiceBank):
    """MIDI events in, blocks of audio out: the notes `bowsynth score` makes of a MIDI file, played live.

    A note is what `score` makes of a MIDI note (`music.score.load_midi_score`): its bow from the velocity and the
    channel's CC2 / CC11 at the note-on (`midi.bow_beta`, `midi.bow_vb`, the one mapping), tuned with the truth's
    sounding ratio, its sustain rolled out by the operator from rest starting at the note-on's frame, window after
    window exactly as offline (window w at the sample nearest w T from the note's start), and at the note-off's
    frame the bow stop (v_B -> 0 over `release` s) and tail by the FDM from the sustain's state there. So each live
    note is the offline note sample for sample (up to float32 rounding: offline may run the numpy loop), and the
    output is their sum times `amp` through a causal DC blocker (offline removes the DC with a zero-phase filter
    over the whole file).

    Real time: `__init__` loads the model, evaluates the trunk on a fine grid, measures or reads every velocity's
    sounding ratio and allocates every buffer (seconds); `process` then creates no numpy array, imports nothing and
    loads nothing: per event it writes a few numbers into a voice's slot and builds the voice's window basis by
    interpolation in place, and renders with the compiled core's voice loop (`_core.Voices`, src/core/voices.cpp;
    the slots: `engines.operator.bank.VoiceBank`), which releases the GIL.

    Parameters
    ----------
    sample_rate : int
        Hz.
    block : int
        The most frames one `process` call renders.
    voices : int
        Slots: notes that may sound at once, release tails included (the callback's budget may hold fewer).
    engine : {'operator', 'fdm'}
        Who plays the sustains.
    model : OperatorModel, path or str, optional
        The operator's model (default: the validated model covering the most velocities).
    a4 : float
        Hz, the tuning of MIDI note numbers.
    release : float, optional
        The bow stop's length (s; default `music.note.RELEASE`).
    amp : float
        The output is amp x the sum of the notes' q = w u (m/s).
    busy_fraction : float
        The share of a block's period that note-ons may take before the rest wait for the next block.
    budget : float
        The share of real time (of each block's period) that the sounding voices' predicted cost may take (BUDGET,
        0.5); a note-on beyond it is dropped (`dropped`); math.inf: no bound.
    costs : VoiceCosts, optional
        The cost model's constants (s); None: measured here, through `process`, once the stream is prepared
        (`_measure_costs`, ~0.1-0.2 s). Given: no measurement (a test's fixed costs, or a machine's measured ones).
    dc_hz : float
        The DC blocker's corner (Hz).
    bend_range : float
        Semitones of the pitch wheel, 0..24.
    windows : {'free', 'locked', 'physics', 'auto'}, optional
        The operator's windows (None: `music.engine_tuning.LIVE_WINDOWS`, free); locked: a note held at its pitch
        in windows locked to it, as `score` renders it.

    Raises
    ------
    UsageError
        A bad voice count, engine, block, bend range, windows or budget.

    Notes
    -----
    What differs from offline, by design:

    - a controller changed while a note sounds acts on the notes struck after it (the file reader follows it within
      the note, with a 5 ms ramp, and tunes the note at the bow's median over the note, which a live note cannot
      know);
    - a note struck with CC2 / CC11 away from neutral is tuned with a ratio interpolated on a grid of measured bows
      (the 127 velocities at neutral controllers are measured exactly before activation);
    - a note the model does not cover (its bow outside the model's box, its pitch too high for one sample per
      window) is played whole by the FDM, as `score --fallback fdm` does;
    - with every voice busy a new note takes the voice nearest its end (releasing first, then the oldest): `stolen`;
    - the callback is bounded by a budget, not by the slots: each sounding voice reserves its predicted share of real
      time (`predicted_share`, from `costs`: a high note rolls more windows a second, so it costs more), the most
      of its sustain and its FDM release tail (which may end it earlier), with its channel's bend and vibrato; a
      note-on that would take their sum (`load`) past `budget` takes a releasing voice whose reservation frees
      enough (`stolen`), else it is not started (`dropped`). A bend or vibrato moved while notes sound adds to the
      load of those notes (it is not refused); where that passes the budget, voices end until it fits, the
      releasing one nearest its end first, then the oldest held (`shed`);
    - note-ons beyond what the block's time allows (`busy_fraction` of the period spent) wait for the next block and
      start at its first frame, in order (`deferred`, `max_defer` frames late); one that waited at most a block is
      caught up there (`_catch_up`: the note struck at its own frame, less the samples before the block), one that
      waited longer starts from rest; past PENDING waiting they are dropped and counted, so a flood of 10,000 notes
      a second keeps the engine on time; malformed MIDI bytes are dropped, counted.

    Examples
    --------
    >>> from bowsynth.live import Stream
    >>> s = Stream(engine="fdm", voices=2, block=256)  # everything prepared here
    >>> on, off = bytes((0x90, 69, 64)), bytes((0x80, 69, 0))  # A4 at velocity 64, then its release
    >>> out = s.process(256, [(0, on), (200, off)])
    >>> out.dtype, out.shape, s.counts["notes"], s.frame
    (dtype('float32'), (256,), 1, 256)
    """

    def __init__(self, sample_rate: int = 44100, block: int = 512, voices: int = 16, engine: str = "operator",
                 model=None, a4: float = 440.0, release: float | None = None, amp: float = AMP,
                 busy_fraction: float = 0.5, dc_hz: float = DC_HZ, bend_range: float = M.BEND_RANGE,
                 windows: str | None = None, budget: float = BUDGET, costs: VoiceCosts | None = None):
        if isinstance(voices, bool) or not isinstance(voices, int) or voices < 1:
            raise UsageError(f"--voices must be a whole number >= 1, got {voices!r}")
        if engine not in ("operator", "fdm"):
            raise UsageError(f"engine must be operator or fdm, got {engine!r}")
        if block < 1:
            raise UsageError(f"block must be >= 1 frame, got {block}")
        if not (math.isfinite(bend_range) and 0 <= bend_range <= 24):
            raise UsageError(f"--bend-range must be 0..24 semitones, got {bend_range:g}")
        if not budget > 0:
            raise UsageError(f"the callback's budget must be a share of real time > 0, got {budget!r}")
        from ..music.engine_tuning import LIVE_WINDOWS, check_windows

        # free: the trained windows; locked: a note held at its pitch in windows locked to it, as `score` renders it
        self.windows = check_windows(windows, LIVE_WINDOWS)
        self.a4, self.bend_range = check_a4(a4), float(bend_range)
        # the semitones a note's pitch may rise while it sounds: its FDM's stride is chosen for the top of them (a
        # note bent two octaves up past the stride chosen at its own pitch broke the scheme's bounds: NaN)
        self.reach = self.bend_range + M.VIBRATO_DEPTH
        self.release_s = RELEASE if release is None else float(release)
        self.amp, self.busy_fraction = float(amp), float(busy_fraction)
        self.a = 100.0  # the friction shape every MIDI note plays (Scene's default, as the file reader's notes)
        ratio_for = None
        if engine == "operator":
            from ..engines.operator.choose import as_model, available_models
            from ..music.engine_tuning import ratio_for_engine

            if model is None:
                model = Tuning.default_model(available_models(), self.a)
            model = as_model(model)
            # auto windows: one choice per velocity for every pitch, as its notes' locks below
            ratio_for = lambda sc: ratio_for_engine(sc, "operator", model, windows=self.windows,  # noqa: E731
                                                    by_pitch=False)[0]
        self.tuning = t = Tuning(self.a, self.a4, sample_rate, ratio_for)
        # the longest window a note may need: the lowest MIDI note (12; r < 1 raises f0), bent down, at the bottom
        # of its vibrato
        lowest = midi_to_hz(12, self.a4) * 2.0 ** (-(self.bend_range + M.VIBRATO_DEPTH) / 12.0)
        super().__init__(sample_rate, block, voices, engine, model if engine == "operator" else None, lowest)
        if engine == "operator":
            d = model.domain
            # a stick-slip bow's notes go to the FDM (_plays says why)
            a_ok = math.isclose(d.a, self.a, rel_tol=1e-9)
            self.covered = np.array([v > 0 and a_ok and bool(d.box_contains(t.v_beta[v], t.v_vb[v]))
                                     and not needs_whole_windows(d, t.v_beta[v]) for v in range(128)])
            # per velocity (neutral controllers): the branch's bow inputs, the correction's gain, the state scaling
            # (NumpyOperator.window_inputs: the offline rollout's own code)
            pin, gain, c, h = self.op.window_inputs(np.stack([t.v_beta, t.v_vb], 1)[None])
            self.v_pin, self.v_gain, self.v_center, self.v_half = pin[0], gain[0], c[0], h[0]
            # locked windows: per velocity the sounding ratio its notes were tuned with and are locked to (the
            # model's own, or with --windows physics / auto the physics' where the model holds it: engine_tuning,
            # cached), NaN where it is not known or auto plays free windows: free windows there
            self.v_lock = np.full(128, np.nan)
            self.v_more = np.zeros(128, np.int64)  # windows a period beyond the fewest (windows.Lock)
            if self.windows != "free":
                from ..music.engine_tuning import held_lock

                lock = [held_lock(model, self.windows, float(t.v_beta[v]), float(t.v_vb[v]), self.a)
                        if self.covered[v] else None for v in range(128)]
                self.v_lock[:] = [np.nan if r is None else r for r in lock]
                self.v_more[:] = [lock_more(r) for r in lock]
        self._allocate_midi(dc_hz)
        # while the stream warms and measures itself every note is admitted, at no cost
        self.costs, self.budget = VoiceCosts(0.0, 0.0, 0.0, 0.0, 0.0), math.inf
        self._warm()
        self.costs = self._measure_costs() if costs is None else VoiceCosts(*map(float, costs))
        self.budget = float(budget)
        self.reset()

    def _allocate_midi(self, dc_hz: float) -> None:
        nv, bl = self.n_voices, self.block
        self.start = np.zeros(nv, np.int64)  # the frame each slot's note started (stealing takes the oldest)
        self.key = np.full(nv, -1, np.int64)  # channel * 128 + note of the slot's note, -1 once released
        self.vb_hold = np.zeros(nv)
        self.chan = np.zeros(nv, np.int64)  # each slot's channel (its bend and vibrato follow it through the release)
        self.sounding = np.full(16 * 128, -1, np.int64)  # slot of each (channel, note) held
        self.cc = np.zeros((16, 128), np.int64)  # each channel's controllers, neutral until a message moves them
        self.cc[:, M.CC_PRESSURE] = M.NEUTRAL[M.CC_PRESSURE]
        self.cc[:, M.CC_EXPRESSION] = M.NEUTRAL[M.CC_EXPRESSION]
        self.bend = np.zeros(16)  # semitones, per channel
        self.depth = np.zeros(16)  # vibrato depth, semitones, per channel
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
        # a deferred note's catch-up (_catch_up): its missed samples rendered here and discarded, the other slots'
        # modes kept aside meanwhile
        self.catch_buf = np.zeros(bl)
        self.catch_modes = np.zeros(nv, self.mode.dtype)
        # the budget (predicted_share): per slot, whether the operator plays it, its windows per sample at its
        # struck pitch, its FDM's share of real time, and what it reserves now (its channel's bend and vibrato in)
        self.c_op = np.zeros(nv, np.bool_)
        self.c_wps, self.c_fdm, self.cost = np.zeros(nv), np.zeros(nv), np.zeros(nv)
        self.load = 0.0  # the sounding voices' reservations: a share of real time
        self._on = np.zeros(nv)  # scratch of the load's sum and of the search for a releasing voice to take
        self._left = np.zeros(nv, np.int64)
        self._skip, self._skip2 = np.zeros(nv, np.bool_), np.zeros(nv, np.bool_)
        self.counts = dict(notes=0, dropped_bytes=0, dropped_busy=0, deferred=0, max_defer=0, stolen=0, dropped=0,
                           shed=0, fdm_notes=0, fallbacks=0, silent=0, out_of_range=0, ignored=0, zero_length=0)

    def _warm(self) -> None:
        """Run every path once, then reset: the first note after activation costs what every later note costs (the
        pages of the model's arrays and the core's code are touched before the first callback)."""
        self._busy_until = math.inf
        on = [(0, bytes((0x90, 69, v))) for v in (64, 100)] + [(1, bytes((0x90, 45, 64))), (2, b"\xb0\x02\x50"),
                                                                 (3, bytes((0x90, 50, 64))), (4, b"\xe0\x00\x50"),
                                                                 (5, b"\xb0\x01\x40")]
        self.process(self.block, on)
        self.process(self.block, [(0, bytes((0x80, 69, 0))), (5, bytes((0x80, 45, 0))), (6, bytes((0x80, 50, 0)))])
        for _ in range(int(0.2 * self.sample_rate / self.block) + 2):
            self.process(self.block, [])
        self.process(self.block, [(0, b"\xe0\x00\x40"), (0, b"\xb0\x01\x00"), (0, b"\xb0\x02\x40")])
        self.reset()

    def reset(self) -> None:
        """Silence: every voice freed, controllers neutral, counters and timings cleared, time back to frame 0.

        Examples
        --------
        >>> s = Stream(engine="fdm", voices=1, block=64)
        >>> _ = s.process(64, [(0, bytes((0x90, 60, 100)))])
        >>> s.reset()
        >>> s.frame, s.counts["notes"], len(s.callback_times())
        (0, 0, 0)
        """
        self.mode[:] = V.FREE
        self.end[:] = -1
        self.key[:] = -1
        self.sounding[:] = -1
        self.n_pending = self.head = 0
        self.ops[16][:] = -1
        self.dc_state[:] = 0.0
        self.bend[:] = 0.0
        self.depth[:] = 0.0
        self.cc[:, M.CC_PRESSURE] = M.NEUTRAL[M.CC_PRESSURE]
        self.cc[:, M.CC_EXPRESSION] = M.NEUTRAL[M.CC_EXPRESSION]
        self.frame = 0
        self.n_times = 0
        self.cost[:] = 0.0
        self.load = 0.0
        for k in self.counts:
            self.counts[k] = 0

    # --- the audio side ---------------------------------------------------------------------------------------

    def process(self, n: int, events=()) -> np.ndarray:
        """Render the next n frames with `events` applied at their frames.

        Parameters
        ----------
        n : int
            Frames, at most `block`.
        events : iterable of (int, bytes)
            (frame offset in this block, MIDI bytes), in time order: note on / off, CC 2 / 11 (the bow), CC 1
            (vibrato), the pitch wheel, CC 120 / 123 (the channel's notes released); system messages are ignored
            and malformed ones dropped, each counted in `counts`.

        Returns
        -------
        numpy.ndarray
            A float32 view of the output, n samples (valid until the next call).

        Examples
        --------
        >>> s = Stream(engine="fdm", voices=2, block=128)
        >>> _ = s.process(128, [(0, b"\\xf8"), (1, b"\\x90\\x45")])  # a clock tick; a note-on one byte short
        >>> s.counts["ignored"], s.counts["dropped_bytes"]
        (1, 1)
        """
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
        # the voices this block ended (their tails done) give their reservations back
        np.not_equal(self.mode, V.FREE, out=self._on)
        self.load = float(np.dot(self._on, self.cost))
        V.dc_block(mix, n, self.dc_r, self.dc_state, self.out)
        self.frame += n
        self.times[self.n_times % TIMES] = time.perf_counter() - t0
        self.n_times += 1
        return self.out[:n]

    def _render(self, off: int, m: int) -> None:
        self.render(self.mix, off, m, self.amp)

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
        time budget lasts. A note due at most one block ago starts as the note it would have been from its own
        frame (_catch_up): from here on its samples are the offline note's; one that waited longer starts here."""
        q = self.pending
        while self.n_pending and time.perf_counter() <= self._busy_until:
            ch, note, vel, due = q[self.head]
            self.head = (self.head + 1) % PENDING
            self.n_pending -= 1
            if vel > 0:
                late = self.frame - int(due)
                self.counts["max_defer"] = max(self.counts["max_defer"], late)
                slot = self._start_note(0, int(ch), int(note), int(vel))
                if slot >= 0 and 0 < late <= self.block:
                    self._catch_up(slot, late)

    def _catch_up(self, slot: int, late: int) -> None:
        """Render the first `late` samples of the note just started in `slot` alone, and discard them: the note then
        goes on from its sample `late` at this block's first frame, as if struck `late` frames ago (the samples it
        missed are not heard; the rest are the offline note's). The other slots are set free meanwhile (the voice
        loop skips a free slot without touching it) and given back their modes after."""
        mode, keep = self.mode, self.catch_modes
        np.copyto(keep, mode)
        mode.fill(V.FREE)
        mode[slot] = keep[slot]
        self.catch_buf[:late] = 0.0
        self.render(self.catch_buf, 0, late, self.amp)
        now = mode[slot]
        np.copyto(mode, keep)
        mode[slot] = now
        self.start[slot] -= late

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

    def _start_note(self, off: int, ch: int, note: int, vel: int) -> int:
        """Start a note at frame `off` of the block: its slot, or -1 where none sounds."""
        if not 12 <= note <= 119:  # the file reader refuses them (C0..B8)
            self.counts["out_of_range"] += 1
            return -1
        key = ch * 128 + note
        if self.sounding[key] >= 0:  # a retrigger: the sounding one ends here (as the file reader does)
            self._note_off(self.sounding[key])
        bow = self._note_bow(ch, note, vel)
        if bow is None:
            self.counts["silent"] += 1
            return -1
        beta, vb, f0, neutral, plays, sounding = bow
        op, wps, fdm = self._shares(f0, beta, plays, sounding)
        cost = self._reserve(op, wps, fdm, ch)
        slot = self._admit(cost)
        if slot < 0:
            return -1
        self.c_op[slot], self.c_wps[slot], self.c_fdm[slot], self.cost[slot] = op, wps, fdm, cost
        self.load += cost
        self.start_slot(slot, f0, beta, vb, self.a, self.reach)
        self.start[slot], self.key[slot], self.vb_hold[slot], self.chan[slot] = self.frame + off, key, vb, ch
        pm, pp = self.pit[0], self.pit[1]
        pp[slot, V.P_B0] = pp[slot, V.P_B1] = self.bend[ch]
        pp[slot, V.P_D0] = pp[slot, V.P_D1] = self.depth[ch]
        pp[slot, V.P_BT] = pp[slot, V.P_DT] = 0.0
        pp[slot, V.P_RATE], pp[slot, V.P_RAMP] = M.VIBRATO_HZ, M.CC_RAMP * self.sample_rate
        pm[slot] = V.LIVE if (self.bend[ch] != 0 or self.depth[ch] != 0) else V.HELD
        self.sounding[key] = slot
        self.counts["notes"] += 1
        if self.engine == "operator":
            if plays:
                pin, gain, center, half = self.ops[9], self.ops[10], self.ops[7], self.ops[8]
                if neutral:
                    pin[slot], gain[slot], center[slot], half[slot] = (self.v_pin[vel], self.v_gain[vel],
                                                                        self.v_center[vel], self.v_half[vel])
                else:
                    self.bow_inputs(slot, beta, vb)
                if self.start_operator(slot, f0, sounding):
                    self.start_rest(slot, beta, vb, self.a, f0)
                    return slot
            self.counts["fdm_notes"] += 1
        self.start_fdm(slot)
        return slot

    def _note_bow(self, ch: int, note: int, vel: int):
        """A note-on's bow and pitch as the channel's controllers set them now: (beta, v_B, f0, at neutral
        controllers, whether the operator plays it, the Lock its windows take or None), or None for a silent bow."""
        t = self.tuning
        c2, c11 = self.cc[ch, M.CC_PRESSURE], self.cc[ch, M.CC_EXPRESSION]
        neutral = c2 == M.NEUTRAL[M.CC_PRESSURE] and c11 == M.NEUTRAL[M.CC_EXPRESSION]
        beta = t.v_beta[vel] if neutral else M.bow_beta(vel, c2)
        vb = t.v_vb[vel] if neutral else M.bow_vb(vel, c11)
        f0 = t.f0[vel, note] if neutral else midi_to_hz(note, self.a4) / t.grid_ratio(beta, vb)
        if not f0 == f0 or vb <= 0 or beta <= 0:  # NaN: a silent bow
            return None
        plays = self.engine == "operator" and bool(self.covered[vel] if neutral else self._plays(beta, vb))
        # locked (a neutral note held at its pitch from its note-on): the model's own period, as `score` locks it; a
        # note bent later keeps its windows, where offline its pitch curve plays free ones
        lock = self.v_lock[vel] if plays and neutral and self.bend[ch] == 0 and self.depth[ch] == 0 else math.nan
        return beta, vb, f0, neutral, plays, (Lock(f0 * lock, self.v_more[vel]) if lock > 0 else None)

    def _pitch_moved(self, ch: int) -> None:
        """The channel's bend or vibrato depth changed: each of its notes (held or releasing) ramps to it from its
        value now (a 5 ms ramp, as the file reader's controllers) and follows it from its next window on."""
        pm, pp = self.pit[0], self.pit[1]
        for slot in range(self.n_voices):
            if self.mode[slot] == V.FREE or self.chan[slot] != ch:
                continue
            s = float(self.pos[slot])
            b = V.ramp(pp[slot, V.P_B0], pp[slot, V.P_B1], pp[slot, V.P_BT], pp[slot, V.P_RAMP], s)
            d = V.ramp(pp[slot, V.P_D0], pp[slot, V.P_D1], pp[slot, V.P_DT], pp[slot, V.P_RAMP], s)
            pp[slot, V.P_B0], pp[slot, V.P_B1], pp[slot, V.P_BT] = b, self.bend[ch], s
            pp[slot, V.P_D0], pp[slot, V.P_D1], pp[slot, V.P_DT] = d, self.depth[ch], s
            pm[slot] = V.LIVE
            # its windows' rate follows the bend, a vibrato rebuilds its basis every window: its reservation too
            cost = self._reserve(self.c_op[slot], self.c_wps[slot], self.c_fdm[slot], ch)
            self.load += cost - self.cost[slot]
            self.cost[slot] = cost
        if self.load > self.budget:
            self._shed()

    def _plays(self, beta: float, vb: float) -> bool:
        """Does the model play this bow (Domain.box_contains for one bow, in scalars)? A point model plays only
        the velocities the table found it covers. A stick-slip bow (grid.needs_whole_windows) leaves its note to the
        FDM: the live voice loop has no whole-window grid yet."""
        d = self.model.domain
        if d.box is None or needs_whole_windows(d, beta):
            return False
        b0, b1, v0, v1 = d.box
        return (b0 <= beta <= b1 or (d.plays_below and 0.0 <= beta <= b0)) and v0 <= vb <= v1

    def _note_off(self, slot: int) -> None:
        """The bow stop from the slot's next sample (VoiceBank.release); a note of zero length is dropped, as the
        file reader drops it."""
        key = self.key[slot]
        if key >= 0:
            self.sounding[key] = -1
        self.key[slot] = -1
        if self.pos[slot] == 0:
            self.mode[slot] = V.FREE
            self.load -= self.cost[slot]
            self.counts["zero_length"] += 1
            return
        fst = self.fdm[0]
        self.release(slot, self.vb_hold[slot], self.release_s, stop_tail(fst[slot, 6], fst[slot, 4] / (2 * math.pi),
                                                                          self.a))

    # --- what it did ------------------------------------------------------------------------------------------

    def callback_times(self) -> np.ndarray:
        """The durations (s) of the last process() calls (up to TIMES of them), a copy."""
        return self.times[:min(self.n_times, TIMES)].copy()

