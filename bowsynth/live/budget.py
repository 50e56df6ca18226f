"""The process callback's budget: what each voice costs (measured through the callback's own path), the share of real
time a note reserves, and which note-on is admitted, steals a releasing voice, or is dropped."""

from __future__ import annotations

import math
import time
from typing import NamedTuple

import numpy as np

from .. import physics
from ..engines.operator import voices as V
from ..engines.operator.windows import locked_window
from ..music import midi as M

# The share of real time the sounding voices' predicted cost may take: half of each period, the other half left for
# the callback's Python, the server, the other clients and whatever else the machine runs. A note-on that would take
# the prediction past it is dropped (counted: `dropped`).
BUDGET = 0.5
# The cost model's measurement (Stream._measure_costs): voices, timed blocks per case (after two untimed ones), and the
# low and high notes whose window rates tell a sample's cost from a window's
CAL_VOICES, CAL_BLOCKS, CAL_LOW, CAL_HIGH = 12, 8, 40, 100
NEVER = np.iinfo(np.int64).max


class VoiceCosts(NamedTuple):
    """What one voice costs the process callback, in seconds: the cost model's constants.

    A voice the operator plays costs `sample` per sample (its samples copied out, the render's per-sample share) and
    `window` per window it rolls: a note rolls one window per period of its f0 (samples per window = T / dtau), so a
    voice at MIDI 100 rolls 33 windows a 512-frame block where one at MIDI 40 rolls one. A voice whose pitch moves (a
    vibrato) rebuilds its window basis every window: `vibrato_sample` per sample and `vibrato_window` per window more.
    The FDM costs `step` per step, `stride` steps a sample (physics.min_oversample: 1 below ~MIDI 90, up to 5 at the
    top). A voice's share of real time is then sample_rate x its cost per sample (Stream.predicted_share)."""

    sample: float
    window: float
    vibrato_sample: float
    vibrato_window: float
    step: float

    def __str__(self) -> str:
        return (f"{1e9 * self.sample:.1f} ns a sample + {1e6 * self.window:.2f} us a window (vibrato "
                f"+{1e9 * self.vibrato_sample:.0f} ns a sample, +{1e6 * self.vibrato_window:.2f} us a window), FDM "
                f"{1e9 * self.step:.0f} ns a step")


class Budgeted:
    """The budget's part of `bowsynth.live.stream.Stream`: its cost model, each note's reservation and the admission
    of a note-on (the stream holds the voices' state, `load` and `costs`)."""

    def _measure_costs(self) -> VoiceCosts:
        """The cost model's constants, measured here through `process` (the callback's own path, on the machine as
        loaded as it is now): blocks of up to CAL_VOICES voices at a low note (MIDI 40: about one window a 512-frame
        block) and a high one (MIDI 100: ~33), held and with a full vibrato, and the high ones played by the FDM;
        each the median of CAL_BLOCKS blocks less an empty block's, per voice. The two window rates tell a sample's
        cost from a window's (VoiceCosts). About 0.1-0.2 s; the stream is reset after."""
        B, n = self.block, min(CAL_VOICES, self.n_voices)
        blocks = CAL_BLOCKS * max(1, CAL_VOICES // n)  # fewer voices: more blocks
        ts = np.zeros(blocks)

        def per_voice(note: int, vel: int, vibrato: bool = False, fdm: bool = False) -> tuple[float, float, int]:
            """A block's seconds per voice (an empty block's over n when note is 0), the voices' windows a sample, and
            their FDM stride."""
            self.reset()
            ev = [(0, bytes((0xB0 | ch, M.CC_MODULATION, 127))) for ch in range(n) if vibrato]
            ev += [(1, bytes((0x90 | ch, note, vel))) for ch in range(n) if note]
            self.process(B, ev)
            if fdm:
                for slot in np.flatnonzero(self.mode != V.FREE):
                    self.start_fdm(int(slot))
            for _ in range(2):
                self.process(B, [])
            for i in range(blocks):
                t0 = time.perf_counter()
                self.process(B, [])
                ts[i] = time.perf_counter() - t0
            wps = 1.0 / float(self.ops[1][0]) if note and self.mode[0] == V.OPERATOR else 0.0
            return float(np.median(ts)) / n, wps, int(self.fdm[1][0, 1])

        def fit(lo, hi) -> tuple[float, float]:
            """(a sample's cost, a window's) from a block's cost per voice at two window rates."""
            (y_lo, w_lo, _), (y_hi, w_hi, _) = lo, hi
            y_lo, y_hi = max(y_lo - empty, 0.0), max(y_hi - empty, 0.0)
            if not w_hi > w_lo:  # one window rate (a model that plays MIDI 100 with the FDM): all per sample
                return max(y_lo, y_hi) / B, 0.0
            window = max((y_hi - y_lo) / (B * (w_hi - w_lo)), 0.0)
            return max(y_lo / B - w_lo * window, 0.0), window

        empty = per_voice(0, 0)[0]
        vel = 64
        if self.engine == "operator":
            covered = np.flatnonzero(self.covered & np.isfinite(self.tuning.f0[:, CAL_HIGH]))
            vel = int(covered[np.argmin(np.abs(covered - 64))]) if len(covered) else 0
        y, _, stride = per_voice(CAL_HIGH, vel or 64, fdm=self.engine == "operator")
        step = max(y - empty, 0.0) / (B * stride)
        if not vel:  # the operator plays no velocity at neutral controllers here: the FDM's cost alone is known
            return VoiceCosts(0.0, 0.0, 0.0, 0.0, step)
        sample, window = fit(per_voice(CAL_LOW, vel), per_voice(CAL_HIGH, vel))
        # a vibrato voice plays free windows (a held one may play locked ones): fitted at its own window rates
        v_sample, v_window = fit(per_voice(CAL_LOW, vel, vibrato=True), per_voice(CAL_HIGH, vel, vibrato=True))
        return VoiceCosts(sample, window, max(v_sample - sample, 0.0), max(v_window - window, 0.0), step)

    def _shares(self, f0: float, beta: float, plays: bool, sounding) -> tuple[bool, float, float]:
        """A note at f0: (does the operator play it, its windows per sample (0 for the FDM), its FDM's share of real
        time (the note whole, or its release tail)). Scalar arithmetic: the operator's window as start_operator
        finds it (locked or free; none fits: the FDM plays it), the FDM's stride as start_slot finds it (for the
        highest pitch the bend and vibrato reach)."""
        sr = self.sample_rate
        fdm = sr * self.costs.step * self.fdm_stride(f0, beta, self.a, self.reach)
        if not plays:
            return False, 0.0, fdm
        window = None if sounding is None else locked_window(self.op.window, f0, sounding)
        spw = self.op.samples_per_window(physics.dtau(f0, sr), window)
        if math.floor(spw) < 1 or math.ceil(spw) + 1 > self.n_max:
            return False, 0.0, fdm
        return True, 1.0 / spw, fdm

    def _reserve(self, op: bool, wps: float, fdm: float, ch: int) -> float:
        """What a voice reserves on channel ch (a share of real time): the most of its sustain (VoiceCosts' samples
        and windows, its windows' rate moved with the bend, the vibrato's rebuilt bases where the channel has one)
        and its FDM (its release tail, a fallback)."""
        if not op:
            return fdm
        c = self.costs
        wps = wps * 2.0 ** (self.bend[ch] / 12.0)  # windows a sample go with f0
        per_sample = c.sample + c.window * wps
        if self.depth[ch] != 0:
            per_sample += c.vibrato_sample + c.vibrato_window * wps
        return max(self.sample_rate * per_sample, fdm)

    def predicted_share(self, note: int, velocity: int = 64, channel: int = 0) -> float:
        """The share of real time a note struck now would reserve (channel's controllers, bend and vibrato as they
        are); NaN where it would not sound (out of range, a silent bow).

        Examples
        --------
        >>> from bowsynth.live.stream import Stream
        >>> s = Stream(engine="fdm", voices=1, costs=(0, 0, 0, 0, 1e-7))  # 0.1 us an FDM step
        >>> round(s.predicted_share(69) / (44100 * 1e-7), 3)  # one step a sample at A4
        1.0
        """
        if not 12 <= note <= 119:
            return math.nan
        bow = self._note_bow(channel, note, velocity)
        if bow is None:
            return math.nan
        beta, _, f0, _, plays, sounding = bow
        return self._reserve(*self._shares(f0, beta, plays, sounding), channel)

    def _admit(self, cost: float) -> int:
        """The slot for a note that reserves `cost`, or -1 (counted: `dropped`). A free slot, else the voice to steal
        (the releasing one nearest its end, else the oldest held one), where the load stays within the budget with
        the note in; else a releasing voice whose reservation frees enough (the one nearest its end); else none."""
        slot = V.pick_slot(self.mode, self.end, self.pos, self.start)
        busy = self.mode[slot] != V.FREE
        if self.load - (self.cost[slot] if busy else 0.0) + cost > self.budget:
            slot = self._releasing(self.load + cost - self.budget)
            if slot < 0:
                self.counts["dropped"] += 1
                return -1
            busy = True
        if busy:  # stolen
            self.counts["stolen"] += 1
            self._end_voice(slot)
        return slot

    def _end_voice(self, slot: int) -> None:
        """The slot's voice ended at once (stolen or shed): its key no longer sounding, its reservation given back."""
        if self.key[slot] >= 0:
            self.sounding[self.key[slot]] = -1
        self.key[slot] = -1
        self.mode[slot] = V.FREE
        self.load -= self.cost[slot]
        self.cost[slot] = 0.0

    def _shed(self) -> None:
        """A bend or vibrato took the sounding voices' reservations past the budget: end voices, as a steal does,
        until they fit again: the releasing voice nearest its end first, then the oldest held one; each counted
        (`shed`). Without it the callback runs past its period for as long as those notes sound (a bend of 24
        semitones rolls four times the windows a second)."""
        while self.load > self.budget:
            slot = self._releasing(0.0)
            if slot < 0:
                left = self._left
                np.copyto(left, self.start)
                np.equal(self.mode, V.FREE, out=self._skip)
                np.copyto(left, NEVER, where=self._skip)
                slot = int(np.argmin(left))
                if left[slot] == NEVER:
                    return
            self._end_voice(slot)
            self.counts["shed"] += 1

    def _releasing(self, at_least: float) -> int:
        """The releasing voice nearest its end among those reserving at least `at_least`, or -1: in numpy calls on
        scratch arrays (no Python loop over the slots, no new array)."""
        left, skip, skip2 = self._left, self._skip, self._skip2
        np.subtract(self.end, self.pos, out=left)
        np.less(self.end, 0, out=skip)  # held
        np.equal(self.mode, V.FREE, out=skip2)
        np.logical_or(skip, skip2, out=skip)
        np.less(self.cost, at_least, out=skip2)
        np.logical_or(skip, skip2, out=skip)
        np.copyto(left, NEVER, where=skip)
        slot = int(np.argmin(left))
        return slot if left[slot] != NEVER else -1
