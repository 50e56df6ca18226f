"""A chord in the streaming engine without JACK: note-ons past the block's time budget wait for the next block and
are caught up there, so that from that block on the chord is `score`'s offline render of the same events; and the
catch-up creates no array in the callback."""

from __future__ import annotations

import math
import tracemalloc

import numpy as np
import pytest

from bowsynth import physics
from bowsynth.engines.operator import voices as V
from bowsynth.live import Stream
from bowsynth.live.budget import BUDGET, VoiceCosts
from test_stream import MODEL, offline

RATE, BLOCK = 44100, 512
CHORD = range(40, 72)  # 32 keys, E2 .. B4


def _play_deferred(s: Stream, events, n: int, late_block: int) -> np.ndarray:
    """Blocks of BLOCK frames; in block `late_block` no note-on fits the time budget (every one waits), in the
    others all do."""
    out = []
    for k, b0 in enumerate(range(0, n, BLOCK)):
        m = min(BLOCK, n - b0)
        s.busy_fraction = -1.0 if k == late_block else 1e9
        out.append(s.process(m, [(f - b0, d) for f, d in events if b0 <= f < b0 + m]).copy())
    return np.concatenate(out)


def test_a_chord_that_waits_a_block_is_caught_up_to_the_offline_chord(tmp_path):
    at = 3 * BLOCK + 200  # struck mid-block: 312 frames before the next block
    ev = [(at, bytes((0x90, n, 64))) for n in CHORD] + [(at + RATE // 2, bytes((0x80, n, 0))) for n in CHORD]
    n = int(0.8 * RATE)
    s = Stream(block=BLOCK, voices=64, model=MODEL)
    out = _play_deferred(s, ev, n, at // BLOCK)
    assert s.counts["deferred"] == 32 and s.counts["max_defer"] == 4 * BLOCK - at and s.counts["notes"] == 32
    ref = offline(tmp_path, ev, n, "operator", s.amp, s.dc_r)
    # not heard: each note's first 312 samples (a bow from rest), and with them the causal DC blocker's memory of
    # the notes' static offset, which fades at its 5 Hz corner (5 % of the peak at the block, 0.01 % 0.2 s on)
    nxt = slice(4 * BLOCK, n)
    a, b = _highpass(out), _highpass(ref)
    assert np.corrcoef(a[nxt], b[nxt])[0, 1] > 0.999
    faded = slice(4 * BLOCK + int(0.2 * RATE), n)
    assert np.max(np.abs(out[faded] - ref[faded])) < 3e-4 * np.max(np.abs(ref))
    # started from rest at the next block instead, 312 frames late, the chord is another sound (NCC ~0.06)
    late = offline(tmp_path, [(f + 4 * BLOCK - at if f == at else f, d) for f, d in ev], n, "operator", s.amp,
                   s.dc_r)
    assert np.corrcoef(_highpass(late)[nxt], b[nxt])[0, 1] < 0.5


def _highpass(x, hz=20.0):
    from scipy.signal import butter, sosfiltfilt

    return sosfiltfilt(butter(4, hz, "highpass", fs=RATE, output="sos"), x)


def test_the_catch_up_creates_no_array(tmp_path):
    """Blocks of 4096 frames: an array of a block's size would be 16 kB or more (as tests/test_stream.py checks the
    callback without waiting notes)."""
    B = 4096
    s = Stream(block=B, voices=40, model=MODEL)
    chord = [(100, bytes((0x90, n, 64))) for n in CHORD]
    for budget in (-1.0, 1e9, 1e9):  # warm: the chord waits, is caught up, sounds
        s.busy_fraction = budget
        s.process(B, chord if budget < 0 else [])
    s.reset()
    tracemalloc.start()
    peaks = []
    try:
        for budget, evs in ((-1.0, chord), (1e9, []), (1e9, [])):
            s.busy_fraction = budget
            base = tracemalloc.get_traced_memory()[0]
            tracemalloc.reset_peak()
            s.process(B, evs)
            peaks.append(tracemalloc.get_traced_memory()[1] - base)
    finally:
        tracemalloc.stop()
    assert s.counts["deferred"] == 32 and s.counts["notes"] == 32
    assert max(peaks) < 8192, peaks


# A voice's cost fixed for the tests below (the machine's own is measured when a Stream is prepared): what they
# admit depends on these numbers only. Close to a 2-core machine's: MIDI 40 reserves its FDM release tail (0.05 ms a
# 512-frame block), MIDI 100 0.14 ms, MIDI 112 0.27 ms.
COSTS = VoiceCosts(sample=10e-9, window=4e-6, vibrato_sample=0.2e-6, vibrato_window=3e-6, step=0.1e-6)
TOP = [(ch, note) for note in range(88, 120) for ch in (0, 1)]  # 64 note-ons, MIDI 88 .. 119, two channels


def _sounding_load(s: Stream) -> float:
    """The sounding voices' reservations, summed afresh."""
    return float(sum(s.cost[v] for v in range(s.n_voices) if s.mode[v] != V.FREE))


def test_a_burst_at_the_top_of_the_keyboard_is_held_to_the_budget_and_a_low_chord_is_not():
    """A 32-key chord at MIDI 40-71 sounds whole (its reservations: a quarter of the budget); then 64 note-ons at
    MIDI 88-119, far more than the budget holds at the top (each rolls 17-100 windows a 512-frame block): the notes the
    budget admits, in order, sound, the others are not started and counted (`dropped`, in play's summary), no voice
    is stolen (64 slots are free), and the sounding voices' predicted cost stays within the budget while they play
    and release. Blocks of 4096 frames: the refusals create no array (a block-sized one would be 16 kB or more)."""
    B = 4096
    s = Stream(block=B, voices=96, model=MODEL, costs=COSTS, busy_fraction=1e9)
    assert s.costs == COSTS and s.budget == BUDGET == 0.5
    share = {n: s.predicted_share(n) for n in range(40, 120)}
    # the cost model: per sample, per window (one a period: samples per window T / dtau), FDM steps for the tail
    spw = s.op.samples_per_window(physics.dtau(s.tuning.f0[64, 100], RATE))
    assert math.isclose(share[100], RATE * (COSTS.sample + COSTS.window / spw))
    assert share[40] == RATE * COSTS.step  # a low note: its release tail (one FDM step a sample) costs the most
    assert sorted(share[n] for n in range(88, 120)) == [share[n] for n in range(88, 120)]  # higher costs more

    s.process(B, [(0, bytes((0x90, n, 64))) for n in CHORD])
    assert s.counts["notes"] == 32 and s.counts["dropped"] == 0 and s.voices_sounding() == 32
    low = sum(share[n] for n in CHORD)
    assert math.isclose(s.load, low) and low < 0.3 * s.budget

    # which of the burst the budget admits, in order (a refused note leaves room for a cheaper one after it)
    load, admitted = low, []
    for ch, n in TOP:
        if load + share[n] <= s.budget:
            load += share[n]
            admitted.append((ch, n))
    assert 0 < len(admitted) <= len(TOP) - 16
    burst = [(i, bytes((0x90 | ch, n, 64))) for i, (ch, n) in enumerate(TOP)]
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        tracemalloc.reset_peak()
        s.process(B, burst)
        peak = tracemalloc.get_traced_memory()[1] - base
    finally:
        tracemalloc.stop()
    assert peak < 8192, peak
    c = s.counts
    assert c["notes"] == 32 + len(admitted) and c["dropped"] == len(TOP) - len(admitted) and c["stolen"] == 0
    assert sorted(int(k) for k in s.key if k >= 0) == sorted([*CHORD] + [ch * 128 + n for ch, n in admitted])
    assert math.isclose(s.load, load) and s.load <= s.budget
    from bowsynth.live.jack_client import _summary

    assert f"dropped {len(TOP) - len(admitted)}" in _summary(s, 0, B, RATE, 1.0)
    # held, then released (each reservation covers its FDM tail): within the budget, block after block
    for evs in [[]] * 3 + [[(0, bytes((0xB0 | ch, 123, 0))) for ch in (0, 1)]] + [[]] * 6:
        s.process(B, evs)
        assert math.isclose(s.load, _sounding_load(s), abs_tol=1e-12) and s.load <= s.budget
    assert s.voices_sounding() == 0 and c["dropped"] == len(TOP) - len(admitted)


def test_a_note_beyond_the_budget_takes_a_releasing_voice_and_a_vibrato_past_it_ends_the_oldest():
    """A budget of 10.5 notes at MIDI 112: of 16 struck, 10 sound. One released, a new note that does not fit takes
    its voice (its reservation frees enough: `stolen`) rather than being dropped. A vibrato moved in on a channel
    that sounds rebuilds its note's window basis every window, which takes the load past the budget: the oldest held
    voice ends (`shed`; a controller is never refused), and a low note struck after it fits."""
    s = Stream(block=BLOCK, voices=64, model=MODEL, costs=COSTS, busy_fraction=1e9)
    one = s.predicted_share(112)
    s.budget = 10.5 * one
    s.process(BLOCK, [(ch, bytes((0x90 | ch, 112, 64))) for ch in range(16)])
    assert s.counts["notes"] == 10 and s.counts["dropped"] == 6 and math.isclose(s.load, 10 * one)
    s.process(BLOCK, [(0, bytes((0x80, 112, 0)))])
    slot = int(np.flatnonzero((s.key < 0) & (s.mode != V.FREE))[0])  # releasing
    assert math.isclose(s.load, 10 * one)  # the tail keeps its reservation
    s.process(BLOCK, [(0, bytes((0x9A, 112, 64)))])  # channel 10: dropped before
    assert s.counts["stolen"] == 1 and s.counts["dropped"] == 6 and s.sounding[10 * 128 + 112] == slot
    assert math.isclose(s.load, 10 * one) and s.load <= s.budget
    s.process(BLOCK, [(0, bytes((0xB1, 1, 127))), (1, bytes((0x9B, 40, 64)))])  # a vibrato on channel 1, then it
    # channel 1's note, struck first of those held, is the oldest: it ends, and the load fits again
    assert s.counts["shed"] == 1 and s.sounding[1 * 128 + 112] < 0 and s.voices_sounding() == 10
    assert s.sounding[11 * 128 + 40] >= 0 and s.counts["dropped"] == 6
    assert s.load <= s.budget and math.isclose(s.load, _sounding_load(s), abs_tol=1e-12)


def test_a_bend_that_takes_the_load_past_the_budget_ends_voices_until_it_fits():
    """A chord at MIDI 100-111 within the budget, then the pitch wheel bent 24 semitones up on its channel: each note
    rolls four times the windows a second, so their reservations pass the budget; voices end, oldest first, until
    the load fits (`shed`, in the status line and the summary), and those left play on, bent, block after block
    within the budget. The same chord bent down sheds nothing."""
    from bowsynth.live.jack_client import _status, _summary

    chord = [(0, bytes((0x90, n, 64))) for n in range(100, 112)]
    for bend, shed in ((0x3FFF, True), (0, False)):
        s = Stream(block=BLOCK, voices=64, model=MODEL, costs=COSTS, busy_fraction=1e9, bend_range=24)
        s.process(BLOCK, chord)
        s.budget = 1.05 * s.load  # the chord fits, with a little room
        assert s.counts["notes"] == 12 and s.counts["dropped"] == 0
        s.process(BLOCK, [(0, bytes((0xE0, bend & 0x7F, bend >> 7)))])
        assert (s.counts["shed"] > 0) == shed and s.voices_sounding() == 12 - s.counts["shed"] > 0
        assert s.load <= s.budget and math.isclose(s.load, _sounding_load(s), abs_tol=1e-12)
        if shed:  # the oldest went: the lowest keys, struck first
            assert all(s.sounding[n] < 0 for n in range(100, 100 + s.counts["shed"]))
            assert f"shed {s.counts['shed']}" in _status(s, 0, BLOCK, RATE)
            assert f"shed {s.counts['shed']}" in _summary(s, 0, BLOCK, RATE, 1.0)
        for _ in range(8):
            out = s.process(BLOCK, [])
            assert np.all(np.isfinite(out)) and np.std(out) > 0 and s.load <= s.budget


@pytest.mark.parametrize("engine", ["operator", "fdm"])
def test_a_note_bent_two_octaves_up_plays_finite(engine):
    """A high note (MIDI 104-118) bent 24 semitones up with a full vibrato: its pitch passes 13 kHz, where the FDM at
    the stride chosen for the struck pitch breaks its bounds (it streamed NaN and inf to JACK); the stride is chosen
    for the top of what the bend range and vibrato reach, so every block stays finite, the voices sounding."""
    for note in (104, 111, 118):
        s = Stream(block=BLOCK, voices=4, engine=engine, costs=COSTS, busy_fraction=1e9, bend_range=24)
        s.budget = math.inf
        s.process(BLOCK, [(0, bytes((0x90, note, 64)))])
        s.process(BLOCK, [(0, bytes((0xE0, 0x7F, 0x7F))), (1, bytes((0xB0, 1, 127)))])
        for _ in range(30):
            out = s.process(BLOCK, [])
            assert np.all(np.isfinite(out)) and np.max(np.abs(out)) <= 1.0, (engine, note)
        assert s.voices_sounding() == 1 and np.std(out) > 0, (engine, note)
