"""A chord in the streaming engine without JACK: note-ons past the block's time budget wait for the next block and
are caught up there, so that from that block on the chord is `score`'s offline render of the same events; and the
catch-up creates no array in the callback."""

from __future__ import annotations

import tracemalloc

import numpy as np

from bowsynth.live import Stream
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
