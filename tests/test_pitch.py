"""Sounding pitch: note names, and notes that sound at the asked pitch (checked against a x100 FDM render)."""

import json
import math

import pytest
from conftest import run_main
from hypothesis import given, settings
from hypothesis import strategies as st

from bowsynth import Scene, UsageError, make_scene
from bowsynth.metrics import cents, f0_estimate
from bowsynth.engines.fdm import render_fdm
from bowsynth.music.notes import midi_to_hz, note_name, note_number, parse_pitch
from bowsynth.music.tuning import SilentNoteError, held_value, sounding_pitch, sounding_ratio, tune


def et(semitones_from_a4, a4=440.0):
    return a4 * 2 ** (semitones_from_a4 / 12)


@pytest.mark.parametrize("name,hz", [("A4", 440.0), ("a4", 440.0), ("C4", et(-9)), ("C#3", et(-20)), ("Db3", et(-20)),
                                     ("Bb2", et(-23)), ("A#2", et(-23)), ("Cb4", et(-10)), ("B#3", et(-9)),
                                     ("F##5", et(-2 + 12)), ("C0", et(-57)), ("B8", et(50)), ("E♭4", et(-6))])
def test_note_names_are_equal_tempered(name, hz):
    assert math.isclose(parse_pitch(name), hz, rel_tol=1e-12)


def test_a4_retunes_and_numbers_pass_through():
    assert math.isclose(parse_pitch("A3", a4=415), 207.5, rel_tol=1e-12)
    assert math.isclose(parse_pitch("C5", a4=432), 432 * 2 ** (3 / 12), rel_tol=1e-12)
    assert parse_pitch("261.5") == 261.5 and parse_pitch(98) == 98.0


@pytest.mark.parametrize("bad,match", [("H4", "German H is B"), ("A10", "outside C0..B8"), ("C-1", "outside C0..B8"),
                                       ("B9", "outside"), ("", "not a note name"), ("A", "not a note name"),
                                       ("4", "between C0"), ("Ax", "not a note name"), ("A#b4", "not a note name"),
                                       ("nan", "between"), ("1e9", "between"), ("Cb0", "outside")])
def test_bad_pitch_names_are_refused(bad, match):
    with pytest.raises(UsageError, match=match):
        parse_pitch(bad)


@pytest.mark.parametrize("a4", [50.0, 5000.0, math.nan, math.inf])
def test_bad_a4_is_refused(a4):
    with pytest.raises(UsageError, match="a4"):
        parse_pitch("A4", a4=a4)


@settings(max_examples=200, deadline=None)
@given(st.integers(12, 119), st.floats(400, 480))
def test_note_names_round_trip(n, a4):
    name = note_name(midi_to_hz(n, a4), a4)
    assert note_number(name) == n
    assert math.isclose(parse_pitch(name, a4), midi_to_hz(n, a4), rel_tol=1e-12)


def test_held_value_of_a_curve_is_its_median_over_the_note():
    assert held_value(120.0) == 120.0
    assert math.isclose(held_value([[0.0, 0.0], [0.05, 150.0]], 2.0), 150.0)  # an attack, then held
    assert math.isclose(held_value([[0.0, 50.0], [1.0, 200.0]], 1.0), 125.0, rel_tol=1e-3)  # a ramp: its middle


# several notes across 65-900 Hz at several bow forces and speeds, including stick-slip (F_B / w > 0.43)
CASES = [("C2", 40.0, 0.1), ("A2", 1000.0, 0.2), ("A4", 100.0, 0.2), ("E5", 300.0, 0.25), ("A5", 1000.0, 0.15)]


@pytest.mark.parametrize("pitch,fb,vb", CASES)
def test_solved_note_sounds_at_the_asked_pitch(pitch, fb, vb):
    """Over the steady second half of a 2 s note, rendered by a x100 FDM (the truth), within 0.2 cents."""
    sc = make_scene(pitch=pitch, fb=fb, vb=vb, duration=2.0)
    assert sc.fb == fb and sc.f0 > parse_pitch(pitch)  # the force is kept; friction lowers the pitch, f0 goes up
    r = render_fdm(sc, oversample=100)
    heard = f0_estimate(r.u, sc.sample_rate, tail=0.5)
    assert abs(cents(heard, parse_pitch(pitch))) < 0.2
    # and without the solve (f0 = pitch) the note is flat by far more than that
    assert cents(sounding_pitch(parse_pitch(pitch), fb, vb), parse_pitch(pitch)) < -1.0


def test_beta_mode_keeps_f_b_over_w():
    t = tune("G3", None, beta=100 / (2 * math.pi * 100), vb=0.2)
    assert math.isclose(t.beta, 100 / (2 * math.pi * 100), rel_tol=1e-12)
    r = render_fdm(Scene(f0=t.f0, fb=t.fb, vb=0.2, duration=2.0), oversample=100)
    assert abs(cents(f0_estimate(r.u, 44100, tail=0.5), parse_pitch("G3"))) < 0.2


def test_ratio_does_not_depend_on_the_measuring_pitch():
    """r is a function of (beta, v_B, a) only: two renders at f0 100 and 700 with the same F_B / w agree."""
    beta = 0.3
    r = sounding_ratio(beta, 0.2, 100.0).r
    for f0 in (100.0, 700.0):
        sc = Scene(f0=f0, fb=beta * 2 * math.pi * f0, vb=0.2, duration=1.0)
        heard = f0_estimate(render_fdm(sc, oversample=50).u, 44100, tail=0.5)
        assert abs(cents(heard, f0 * r)) < 0.05


@pytest.mark.parametrize("vb,why", [(0.05, "damps the mass"), (0.35, "grows too slowly")])
def test_notes_that_do_not_speak_are_refused(vb, why):
    with pytest.raises(SilentNoteError, match=why):
        make_scene(pitch="A4", fb=100.0, vb=vb)


def test_no_bow_no_note():
    with pytest.raises(SilentNoteError, match="F_B = 0"):
        sounding_ratio(0.0, 0.2, 100.0)
    assert tune("A4", 0.0).f0 == 440.0  # a free oscillator sounds at f0


@pytest.mark.parametrize("args,match", [
    (["--pitch", "H4"], "German H"), (["--pitch", "A10"], "outside C0..B8"), (["--pitch", "C-1"], "outside"),
    (["--pitch", "A4", "--f0", "100"], "pitch or as f0"), (["--a4", "415"], "give --pitch too"),
    (["--pitch", "A4", "--vb", "0.05"], "does not speak"), (["--pitch", "A4", "--a4", "4000"], "--a4 must be in"),
])
def test_cli_render_bad_pitch_is_one_line_exit_2_nothing_written(tmp_path, capsys, monkeypatch, args, match):
    out = tmp_path / "x.wav"
    code, _, err = run_main(["render", str(out), "--method", "fdm", *args], capsys, monkeypatch)
    assert code == 2 and match in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_cli_render_pitch(tmp_path, capsys, monkeypatch):
    from bowsynth.io.audio import read_wav

    out = tmp_path / "a.wav"
    code, so, err = run_main(["render", str(out), "--method", "fdm", "--pitch", "Bb3", "--fb", "200", "-d", "0.5"],
                             capsys, monkeypatch)
    assert code == 0, err
    sc = read_wav(out).scene
    # --method fdm: tuned with the audio-rate FDM's own ratio (its dispersion), not the truth's
    from bowsynth.music.engine_tuning import fdm_ratio

    assert sc.fb == 200 and math.isclose(sc.f0, tune("Bb3", 200.0, ratio=fdm_ratio(44100)).f0)
    assert not math.isclose(sc.f0, tune("Bb3", 200.0).f0, rel_tol=1e-6)
    assert "233.08 Hz (A#3)" in so and "tuned for the FDM at x1" in so


def test_score_notes_are_tuned_for_the_engine_that_plays_them(tmp_path, capsys, monkeypatch):
    """An A5 in a score played by the audio-rate FDM sounds at 880 Hz: tuned with the FDM's own ratio (its dispersion
    made it +2.2 cents sharp when tuned with the truth's). Measured on the written mix, in a real score run."""
    from bowsynth.metrics import cents, f0_estimate
    from bowsynth.io.audio import read_wav

    (tmp_path / "a5.toml").write_text('[[voice]]\nname = "v"\n[[voice.note]]\npitch = "A5"\nfb = 553.0\n'
                                      'duration = 2.0\nrelease = 0.0\n')
    out = tmp_path / "a5.wav"
    code, so, err = run_main(["score", "--score", str(tmp_path / "a5.toml"), "--method", "fdm", "--mix", str(out)],
                             capsys, monkeypatch)
    assert code == 0, err
    x = read_wav(out).samples
    sr = 44100
    heard = cents(f0_estimate(x[int(0.8 * sr):int(1.5 * sr)], sr, tail=1.0), 880.0)
    assert abs(heard) < 0.3, heard
    # the same note tuned with the truth's ratio is the sharp one this replaced
    from bowsynth.music.engine_tuning import fdm_ratio
    from bowsynth.music.tuning import tune

    assert cents(tune("A5", 553.0).f0, tune("A5", 553.0, ratio=fdm_ratio(44100)).f0) > 1.5


# --- the on-disk table of sounding ratios ---------------------------------------------------------------------------

@pytest.fixture
def fresh_cache(tmp_path, monkeypatch):
    """An empty cache directory, and no ratio remembered by this process."""
    from bowsynth.music import tuning as pitch

    monkeypatch.setenv("BOWSYNTH_CACHE", str(tmp_path / "cache"))
    monkeypatch.setattr(pitch, "_ratios", pitch.DiskTable("sounding-ratio", pitch.RATIO_VERSION))
    pitch.sounding_ratio.cache_clear()
    yield tmp_path / "cache"
    pitch.sounding_ratio.cache_clear()


def _forget(monkeypatch):
    """A new process: nothing in memory, and measuring is forbidden (only the disk can answer)."""
    from bowsynth.music import tuning as pitch

    pitch.sounding_ratio.cache_clear()
    monkeypatch.setattr(pitch, "_ratios", pitch.DiskTable("sounding-ratio", pitch.RATIO_VERSION))
    monkeypatch.setattr(pitch, "measure_ratio", lambda *a: pytest.fail("measured again"))


def test_sounding_ratios_are_remembered_on_disk(fresh_cache, monkeypatch):
    from bowsynth.music import tuning as pitch

    first = pitch.sounding_ratio(0.159, 0.2, 100.0)
    with pytest.raises(pitch.SilentNoteError) as silent:
        pitch.sounding_ratio(0.159, 0.05, 100.0)  # a bow stop: does not speak
    assert len(list((fresh_cache / "sounding-ratio").rglob("*.json"))) == 2
    _forget(monkeypatch)
    assert pitch.sounding_ratio(0.159, 0.2, 100.0) == first  # the same floats, bit for bit
    with pytest.raises(pitch.SilentNoteError) as again:
        pitch.sounding_ratio(0.159, 0.05, 100.0)
    assert str(again.value) == str(silent.value)
    assert pitch.tune("A4", fb=None, beta=0.159, vb=0.2).f0 == pytest.approx(440 / first.r)


def test_an_engines_failed_measurement_is_remembered_on_disk(fresh_cache, monkeypatch):
    """A model that cannot hold a bow from rest fails the same way every time: the failure is kept and raised again
    from the table, its kind and its words, without measuring (measured afresh it cost 1.1 s of a warm render)."""
    from bowsynth.errors import DomainError
    from bowsynth.music import engine_ratio as pitch

    calls = []

    def leaves():
        calls.append("leaves")
        raise DomainError("model x left its states at t = 0.100 s")

    def silent():
        calls.append("silent")
        return float("nan")
    with pytest.raises(DomainError, match="left its states"):
        pitch.engine_ratio("operator x", 1.683, 0.0711, 100.0, leaves)
    with pytest.raises(pitch.SilentNoteError, match="does not speak with this engine"):
        pitch.engine_ratio("operator y", 1.683, 0.0711, 100.0, silent)
    assert calls == ["leaves", "silent"]
    _forget(monkeypatch)
    never = lambda: pytest.fail("measured again")  # noqa: E731
    with pytest.raises(DomainError, match="left its states at t = 0.100 s"):
        pitch.engine_ratio("operator x", 1.683, 0.0711, 100.0, never)
    with pytest.raises(pitch.SilentNoteError, match="does not speak with this engine"):
        pitch.engine_ratio("operator y", 1.683, 0.0711, 100.0, never)
    assert pitch.engine_ratio("operator z", 1.683, 0.0711, 100.0, lambda: 0.99) == 0.99  # another key: measured


def _entry(fresh_cache):
    (path,) = (fresh_cache / "sounding-ratio").rglob("*.json")
    return path


@pytest.mark.parametrize("content", [b"", b"{not json", b"\xff\xfe\x00", b'{"version": "0", "key": "x", "value": 1}',
                                     b'{"version": null, "entries": []}', b"[1, 2]"])
def test_a_bad_cache_entry_is_measured_over(fresh_cache, monkeypatch, content):
    """Truncated, binary, foreign-version or wrong-shaped entries are ignored and replaced, never an error."""
    from bowsynth.music import tuning as pitch

    r = pitch.sounding_ratio(0.159, 0.2, 100.0)
    _entry(fresh_cache).write_bytes(content)
    pitch.sounding_ratio.cache_clear()
    monkeypatch.setattr(pitch, "_ratios", pitch.DiskTable("sounding-ratio", pitch.RATIO_VERSION))
    assert pitch.sounding_ratio(0.159, 0.2, 100.0) == r
    doc = json.loads(_entry(fresh_cache).read_text())
    assert doc["version"] == pitch.RATIO_VERSION and doc["value"]["r"] == r.r


def test_an_edited_entry_is_measured_again(fresh_cache, monkeypatch):
    from bowsynth.music import tuning as pitch

    r = pitch.sounding_ratio(0.159, 0.2, 100.0)
    path = _entry(fresh_cache)
    doc = json.loads(path.read_text())
    doc["value"] = {"r": "fast"}
    path.write_text(json.dumps(doc))
    pitch.sounding_ratio.cache_clear()
    monkeypatch.setattr(pitch, "_ratios", pitch.DiskTable("sounding-ratio", pitch.RATIO_VERSION))
    assert pitch.sounding_ratio(0.159, 0.2, 100.0) == r


def test_no_cache_when_off_or_unwritable(fresh_cache, tmp_path, monkeypatch):
    from bowsynth.music import tuning as pitch

    monkeypatch.setenv("BOWSYNTH_CACHE", "off")
    assert pitch.sounding_ratio(0.159, 0.2, 100.0).r > 0
    assert not fresh_cache.exists()
    blocker = tmp_path / "a-file"
    blocker.write_text("not a directory")  # unwritable even for root: the cache directory cannot be made
    monkeypatch.setenv("BOWSYNTH_CACHE", str(blocker / "sub"))
    pitch.sounding_ratio.cache_clear()
    monkeypatch.setattr(pitch, "_ratios", pitch.DiskTable("sounding-ratio", pitch.RATIO_VERSION))
    assert pitch.sounding_ratio(0.159, 0.2, 100.0).r > 0  # measured, not remembered, no error
    assert blocker.read_text() == "not a directory"
    monkeypatch.setenv("BOWSYNTH_CACHE", str(tmp_path))
    from bowsynth.io.cache import DiskTable

    t = DiskTable("link", "v")
    link = t.entry_path("k")
    link.parent.mkdir(parents=True)
    link.symlink_to(tmp_path / "target.json")
    t.put("k", 1)  # the link is replaced by a file; what it pointed to is never written
    assert not (tmp_path / "target.json").exists() and json.loads(link.read_text())["value"] == 1
    assert not link.is_symlink()


@pytest.mark.parametrize("pitch, fb, engine", [("A5", 553.0, "fdm"), (1000.0, 900.0, "fdm"),
                                               (146.83, 193.7, "operator")])
def test_a_note_is_tuned_by_the_engine_that_plays_it(pitch, fb, engine):
    """The audio-rate FDM's dispersion makes A5 +1.9 cents sharp and 1 kHz +3.0 when tuned with the truth's ratio;
    the range model plays its own ratio (-0.30 cents here): tuned with the engine's own, each sounds within 0.1 cent."""
    from bowsynth import api
    from bowsynth.metrics import cents, f0_estimate
    from bowsynth.music.notes import parse_pitch
    from bowsynth.music.request import make_scene

    hz = parse_pitch(pitch)
    base = make_scene(pitch=pitch, fb=fb, vb=0.2, duration=3.0)
    ratio, by = api.tuning_for(base, engine)
    assert ratio is not None, by
    sc = make_scene(pitch=pitch, fb=fb, vb=0.2, duration=3.0, ratio=ratio)
    r = api.render(sc, engine=engine)
    assert abs(cents(f0_estimate(r.q[len(r.q) // 3:], sc.sample_rate, tail=1.0), hz)) < 0.1
    if engine == "fdm":  # and the truth's tuning is measurably off there: the test can tell the two apart
        r0 = api.render(base, engine="fdm")
        assert abs(cents(f0_estimate(r0.q[len(r0.q) // 3:], sc.sample_rate, tail=1.0), hz)) > 1.0


def test_a_note_with_a_bow_stop_is_tuned_with_the_lock_it_plays_in():
    """`render --pitch A3 --fb 1382.3 --vb 0.2@0,0.2@1.8,0@1.9 --windows physics`: its windows lock to the held bow
    (Scene.held_bow), so its f0 is solved with the physics' ratio the lock plays, and the held part sounds A3 within
    0.1 cent (0.001 measured)."""
    from bowsynth import api
    from bowsynth.metrics import cents, f0_estimate
    from bowsynth.music.request import make_scene

    kw = dict(pitch="A3", fb=1382.3, vb=[(0.0, 0.2), (1.8, 0.2), (1.9, 0.0)], duration=2.5)
    ratio, by = api.tuning_for(make_scene(**kw), "operator", windows="physics")
    assert "in physics windows" in by
    sc = make_scene(**kw, ratio=ratio)
    r = api.render(sc, windows="physics")
    assert r.info.windows
    sr = sc.sample_rate
    assert abs(cents(f0_estimate(r.p[sr // 2:int(1.8 * sr)], sr), 220.0)) < 0.1


def test_bracketed_root_finds_roots_of_steep_and_flat_functions():
    from bowsynth.music.tuning import _bracketed_root

    for h, root in [(lambda x: x ** 3 - 2.0, 2 ** (1 / 3)), (lambda x: math.exp(5 * x) - 3.0, math.log(3) / 5),
                    (lambda x: 1200 * math.log2(1 + math.atan(x - 0.3) / 10), 0.3)]:
        x = _bracketed_root(h, -1.0, 2.0, h(-1.0), h(2.0))
        assert abs(x - root) < 1e-8 or abs(h(x)) < 1e-6, (x, root)  # to 1e-6 cents, as tune asks


def test_a_bow_the_audio_rate_fdm_never_settles_on_still_renders(tmp_path, capsys, monkeypatch, fresh_cache):
    """A5 at F_B 1000, v_B 0.15: the solve passes bows where the scheme at ~43 samples a period settles on no period
    (its pitch is undefined there, where the truth's is not); the note is tuned with the truth's ratio at those bows
    and renders, instead of refusing a note the truth plays."""
    from bowsynth.music.engine_tuning import fdm_measured_ratio, fdm_ratio

    bow = (0.1563374726295082, 0.15, 100.0)  # a bow the solve tries on the way (measured), at f0 1018.02 Hz
    with pytest.raises(SilentNoteError):
        fdm_measured_ratio(*bow, 1018.0217219518704, 44100)
    assert fdm_ratio(44100)(*bow, 1018.0217219518704) == sounding_ratio(*bow).r
    code, out, err = run_main(["render", "--pitch", "A5", "--fb", "1000", "--vb", "0.15", "--method", "fdm", "-d",
                               "0.3", str(tmp_path / "a5.wav")], capsys, monkeypatch)
    assert code == 0 and "A5" in out and (tmp_path / "a5.wav").exists(), out + err


@pytest.mark.parametrize("bad", ["0.9", None, float("inf"), 1e308, 0.9 * 1.06, -0.9, {"r": 0.9}, "missing"])
def test_a_poisoned_engine_ratio_entry_is_measured_again_never_trusted(bad, tmp_path, monkeypatch):
    """An engine's cached sounding ratio is data from outside: of the wrong type, not finite, out of range or edited
    by 6 % (101 cents from the physics' ratio), it is measured again, and the measurement replaces it; a plausible
    entry is read as it is."""
    import json

    from bowsynth.music import engine_ratio as tuning
    from bowsynth.music.ratio_map import physics_ratio

    monkeypatch.setenv("BOWSYNTH_CACHE", str(tmp_path))
    monkeypatch.setattr(tuning, "_ENGINE_RATIOS", {})
    beta, vb = 0.159, 0.2
    good = physics_ratio(beta, vb).r * 2 ** (0.3 / 1200)
    calls = []

    def measure():
        calls.append(1)
        return good

    def poisoned(value):
        table = tuning.DiskTable("sounding-ratio", "poison")
        key = tuning.ratio_key("operator test", beta, vb, 100.0)
        path = table.entry_path(key)
        path.parent.mkdir(parents=True, exist_ok=True)
        doc = {"version": "poison", "key": key}
        if value != "missing":
            doc["value"] = {"r": value}
        path.write_text(json.dumps(doc))
        monkeypatch.setattr(tuning, "_ratios", tuning.DiskTable("sounding-ratio", "poison"))
        tuning._ENGINE_RATIOS.clear()
        return tuning.engine_ratio("operator test", beta, vb, 100.0, measure, physics_ratio)

    assert poisoned(bad) == good and calls == [1]
    assert poisoned(good) == good and calls == [1]  # a plausible entry: read, not measured
