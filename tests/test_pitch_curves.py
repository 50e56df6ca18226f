"""Pitch that moves within a note: a scene's f0 curve in the FDM (every step) and the operator (every window), in
scores (pitch breakpoints, cents), in MIDI files (pitch wheel, CC1) and live (the same messages, the same notes)."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

from bowsynth import Scene
from bowsynth.engines.fdm import render_fdm
from bowsynth.metrics import f0_estimate

sys.path.insert(0, str(Path(__file__).resolve().parent))
from test_stream import MODEL, offline, play  # noqa: E402

RATE = 44100
BETA, VB = 0.1591549, 0.2


def glide(points, duration):
    """A scene whose f0 follows `points` with F_B / w held (as a MIDI note's bow)."""
    return Scene(f0=points, fb=[(t, BETA * 2 * math.pi * f) for t, f in points], vb=VB, duration=duration)


def pitch(x, a, b):
    return f0_estimate(x[int(a * RATE):int(b * RATE)], RATE, tail=1.0)


def cents(f, g):
    return 1200 * math.log2(f / g)


def test_the_fdm_follows_a_glissando_to_the_pitch_a_held_note_plays():
    r = render_fdm(glide([(0.0, 200.0), (0.6, 200.0), (1.0, 400.0)], 1.6))
    lo = render_fdm(glide([(0.0, 200.0)], 0.6))
    hi = render_fdm(Scene(f0=400.0, fb=BETA * 2 * math.pi * 400, vb=VB, duration=1.6))
    assert abs(cents(pitch(r.q, 0.3, 0.6), pitch(lo.q, 0.3, 0.6))) < 0.01
    # after the glide the mass keeps its amplitude and settles to the held note's pitch within a few periods
    assert abs(cents(pitch(r.q, 1.2, 1.6), pitch(hi.q, 1.2, 1.6))) < 0.05
    assert r.u.shape == r.q.shape and np.all(np.isfinite(r.u))


def test_the_operator_plays_a_pitch_curve_per_window_near_the_fdm():
    from bowsynth.engines.operator.engine import render_operator

    sc = glide([(0.0, 200.0), (0.6, 200.0), (1.0, 400.0)], 1.6)
    op = render_operator(sc, model=MODEL)
    ref = render_fdm(sc, oversample=4)
    assert op.info.loop == "per-window pitch"
    for a, b in ((0.3, 0.6), (1.2, 1.6)):
        assert abs(cents(pitch(op.q, a, b), pitch(ref.q, a, b))) < 1.5


def test_a_pitch_curve_needs_a_held_bow_for_the_operator():
    from bowsynth.errors import SceneError
    from bowsynth.engines.operator.engine import render_operator

    with pytest.raises(SceneError, match="--method fdm"):
        render_operator(Scene(f0=[(0, 200.0), (1, 300.0)], fb=100.0, vb=VB, duration=1.0), model=MODEL)


def test_a_score_takes_pitch_breakpoints_and_cents(tmp_path):
    from bowsynth.music import tuning as P
    from bowsynth.music.score import load_toml_score

    path = tmp_path / "s.toml"
    path.write_text('[defaults]\nbeta = 0.15915494\nvb = 0.2\n[[voice]]\nname = "v"\n[[voice.note]]\nstart = 0.0\n'
                    'duration = 1.0\npitch = [[0.0, "A3"], [0.5, "A3"], [0.8, 440.0]]\n[[voice.note]]\nstart = 1.0\n'
                    'duration = 1.0\npitch = "A3"\ncents = [[0.0, 0.0], [0.5, 30.0], [1.0, -30.0]]\n')
    a, b = load_toml_score(path)
    ratio = P.sounding_ratio(0.15915494, 0.2).r
    assert a.scene.pitch_varies and a.scene.f0_at(0.2) == pytest.approx(220.0 / ratio)
    assert a.scene.f0_at(0.9) == pytest.approx(440.0 / ratio)
    assert a.scene.fb_at(0.9) == pytest.approx(0.15915494 * 2 * math.pi * 440.0 / ratio)
    assert cents(b.scene.f0_at(0.5), 220.0 / ratio) == pytest.approx(30.0, abs=1e-6)
    assert cents(b.scene.f0_at(0.75), 220.0 / ratio) == pytest.approx(0.0, abs=1e-6)


def _midi(path, msgs):
    import mido

    mid = mido.MidiFile(ticks_per_beat=441)
    tr = mido.MidiTrack()
    mid.tracks.append(tr)
    tr.append(mido.MetaMessage("set_tempo", tempo=10000, time=0))
    last = 0
    for f, m in msgs:
        tr.append(m.copy(time=f - last))
        last = f
    mid.save(path)


def test_a_midi_file_bends_with_the_pitch_wheel_and_vibrates_with_cc1(tmp_path):
    import mido

    from bowsynth.music import tuning as P
    from bowsynth.music.score import load_midi_score

    path = tmp_path / "b.mid"
    _midi(path, [(0, mido.Message("control_change", control=1, value=127)), (0, mido.Message("note_on", note=57,
              velocity=64)), (44100, mido.Message("pitchwheel", pitch=8191)), (88200, mido.Message("note_off",
              note=57))])
    (n,) = load_midi_score(path)
    f0 = 220.0 / P.sounding_ratio(0.1591549, 0.2).r
    t = np.arange(0.0, 0.9, 0.001)
    c = 1200 * np.log2(n.scene.f0_at(t) / f0)
    assert c.max() == pytest.approx(50.0, abs=0.5) and c.min() == pytest.approx(-50.0, abs=0.5)  # CC1 127: +-50
    late = 1200 * np.log2(n.scene.f0_at(np.arange(1.1, 1.9, 0.001)) / f0)
    assert (late.max() + late.min()) / 2 == pytest.approx(200.0, abs=0.5)  # the full bend: +2 semitones
    (flat,) = load_midi_score(path, bend_range=12.0)
    assert 1200 * math.log2(flat.scene.f0_at(1.5) / f0) == pytest.approx(1200 + 50 * math.sin(
        2 * math.pi * 5.5 * 1.5), abs=1.0)


@pytest.mark.parametrize("method", ["operator", "fdm"])
def test_live_bend_and_vibrato_are_the_offline_notes_pitch(tmp_path, method):
    from bowsynth.live import Stream

    # A3, CC1 at 76 (+-30 cents) from its start, bent up a semitone at 1 s, released at 2 s
    ev = [(0, b"\xb0\x01\x4c"), (100, b"\x90\x39\x40"), (44100, bytes((0xE0, 0x00, 0x50))), (88200, b"\x80\x39\x00")]
    s = Stream(block=512, voices=2, engine=method, model=MODEL if method == "operator" else None)
    n = 92000
    out = play(s, ev, n, 512)
    ref = offline(tmp_path, ev, n, method, s.amp, s.dc_r)
    assert np.corrcoef(out, ref)[0, 1] > 0.9999
    for a, b in ((0.5, 0.9), (1.5, 1.9)):
        assert abs(cents(pitch(out, a, b), pitch(ref, a, b))) < 0.05
