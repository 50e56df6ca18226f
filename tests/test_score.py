"""Many voices: a batched rollout equals the voices rendered one by one; scores and mixes from the CLI."""

from pathlib import Path

import numpy as np
from conftest import run_main, shipped_pick

from bowsynth import Scene
from bowsynth.engines.operator.engine import render_operator
from bowsynth.engines.operator.modelfile import load_model
from bowsynth.io.audio import read_wav
from bowsynth.music.score import load_score


def test_batched_rollout_equals_single_voices(tiny_model):
    m = load_model(tiny_model)
    scenes = [Scene(fb=100, duration=0.05), Scene(fb=100, duration=0.03, q0=0.001, p0=0.002),
              Scene(fb=300, f0=300, duration=0.05)]
    batch = render_operator(scenes, model=m)
    for sc, r in zip(scenes, batch):
        one = render_operator(sc, model=m)
        assert len(r.q) == sc.n_samples
        # the correction term is summed in float32, whose rounding depends on the BLAS blocking
        tol = 1e-5 * np.abs(one.q).max()
        np.testing.assert_allclose(r.q, one.q, rtol=0, atol=tol)
        np.testing.assert_allclose(r.p, one.p, rtol=0, atol=tol)


def test_batch_loop_equals_voice_loop(tiny_model):
    from bowsynth.engines.operator.rollout import BATCH_FROM, rollout_states

    m = load_model(tiny_model)
    sc = Scene(fb=100)
    x0 = np.array([[0.001 * i, -0.002 * i] for i in range(BATCH_FROM)])
    dt = sc.omega / sc.sample_rate
    q, p, fail = rollout_states(m, x0, 2000, dt, check_domain=False, loop="core-batch")
    assert np.all(fail[:, 0] == -1)
    for i in (0, BATCH_FROM - 1):
        q1, p1, _ = rollout_states(m, x0[i:i + 1], 2000, dt, check_domain=False)
        tol = 1e-5 * np.abs(q1).max()
        np.testing.assert_allclose(q[i], q1[0], rtol=0, atol=tol)
        np.testing.assert_allclose(p[i], p1[0], rtol=0, atol=tol)


def test_score_file_and_mix(tmp_path, tiny_model, monkeypatch, capsys):
    score = tmp_path / "chord.toml"
    score.write_text('[defaults]\nduration = 0.05\nfb = 100.0\n\n[[voice]]\nname = "root"\n\n'
                     '[[voice]]\nname = "fifth"\nf0 = 150.0\nfb = 150.0\n')
    voices = load_score(score)
    assert [v.name for v in voices] == ["root", "fifth"] and voices[1].scene.beta == voices[0].scene.beta
    code, out, err = run_main(["score", "--score", str(score), "--model", str(tiny_model), str(tmp_path / "v")],
                              capsys, monkeypatch)
    assert code == 0, err
    assert read_wav(tmp_path / "v" / "fifth.wav").scene.f0 == 150.0
    code, out, err = run_main(["score", "--score", str(score), "--model", str(tiny_model), "--mix",
                               str(tmp_path / "mix.wav")], capsys, monkeypatch)
    assert code == 0, err
    mix = read_wav(tmp_path / "mix.wav")
    assert mix.meta is None and np.max(np.abs(mix.samples)) > 0.5  # (write_wav refuses non-finite samples)
    code, out, err = run_main(["score", "--presets", "paper-fb10,paper-fb100", "--method", "fdm", "-d", "0.05",
                               str(tmp_path / "p")], capsys, monkeypatch)
    assert code == 0 and sorted(p.name for p in (tmp_path / "p").iterdir()) == ["notes.json", "paper-fb10.wav",
                                                                               "paper-fb100.wav"]


def test_voices_without_a_named_model_share_one_rollout(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # no ./models: one shipped model is picked for both (same F_B / w, other pitches)
    scenes = [Scene(fb=100, duration=0.02), Scene(fb=150, f0=150, duration=0.02, q0=0.001)]
    pick = shipped_pick(scenes[0])
    assert shipped_pick(scenes[1]).path == pick.path
    renders = render_operator(scenes)
    assert [r.info.batched for r in renders] == [2, 2]
    assert all(Path(r.info.model_path).resolve() == pick.path.resolve() for r in renders)


def test_score_fallback_finishes_stray_voices(tmp_path, tiny_model, monkeypatch, capsys):
    m = load_model(tiny_model)
    d = m.domain  # a thin domain, so the voices leave it within a few windows
    d.mask[:] = False
    d.mask[d.mask.shape[0] // 2 - 1: d.mask.shape[0] // 2 + 1, :] = True
    d.q_lo, d.q_hi = -1e-3, 1e-3
    small = tmp_path / "small.safetensors"
    m.save(small)
    args = ["score", "--presets", "paper-fb100,paper-fb100", "-d", "0.1", "--model", str(small)]
    code, out, err = run_main([*args, str(tmp_path / "v")], capsys, monkeypatch)
    assert code == 1 and "voice 1: the rollout left" in err and not (tmp_path / "v").exists()
    code, out, err = run_main([*args, "--fallback", "fdm", str(tmp_path / "v")], capsys, monkeypatch)
    assert code == 0, err
    # the two notes are one scene, rendered once (render_notes): the line is said once, for both
    assert out.count("finished with the FDM") == 1 and "paper-fb100 and 1 more notes: note: voice 1: the rollout" in out
    assert read_wav(tmp_path / "v" / "paper-fb100.wav").meta["method"] == "operator+fdm"
    assert sorted(p.name for p in (tmp_path / "v").iterdir()) == ["notes.json", "paper-fb100-2.wav",
                                                                   "paper-fb100.wav"]
    stem = read_wav(tmp_path / "v" / "paper-fb100-2.wav")
    assert stem.meta["method"] == "operator+fdm" and np.all(np.isfinite(stem.samples))  # continuation: test_fallback
    assert sorted(p.name for p in (tmp_path / "v").iterdir()) == ["notes.json", "paper-fb100-2.wav",
                                                                   "paper-fb100.wav"]
    assert np.all(np.isfinite(read_wav(tmp_path / "v" / "paper-fb100-2.wav").samples))


# --- the score format (docs/score.md) -----------------------------------------------------------------------------

import json  # noqa: E402
import math  # noqa: E402

import pytest  # noqa: E402
import soundfile as sf  # noqa: E402

from bowsynth.metrics import cents, f0_estimate  # noqa: E402
from bowsynth.music.notes import parse_pitch  # noqa: E402
from bowsynth.music.tuning import tune  # noqa: E402

SCORE = '''
a4 = 442.0
[defaults]
beta = 0.15915494309189535
vb = 0.2
release = 0.04

[[voice]]
name = "bass"
fb = 120.0
[[voice.note]]
start = 0.0
duration = 0.6
pitch = "C3"

[[voice]]
name = "tune"
[[voice.note]]
start = 0.1
duration = 0.3
pitch = "E4"
[[voice.note]]
start = 0.3
duration = 0.3
pitch = "G4"
vb = [[0.0, 0.15], [0.2, 0.25]]
[[voice.note]]
start = 0.3
duration = 0.2
f0 = 600.0
preset = "paper-fb1000"
'''


def test_score_notes_pitches_curves_and_layers(tmp_path):
    p = tmp_path / "s.toml"
    p.write_text(SCORE)
    notes = load_score(p)
    assert [(n.name, n.start, n.hold) for n in notes] == [("bass", 0.0, 0.6), ("tune", 0.1, 0.3), ("tune", 0.3, 0.3),
                                                          ("tune", 0.3, 0.2)]
    bass, e4, g4, f600 = notes
    # the voice's fb replaces the defaults' beta; the note is tuned with it to C3 at A4 = 442
    assert bass.scene.fb_at(0.3) == 120.0 and math.isclose(bass.scene.f0, tune(parse_pitch("C3", 442), 120.0).f0)
    # beta notes keep F_B / w: fb = beta w
    assert math.isclose(e4.scene.beta_range[0], 0.15915494309189535, rel_tol=1e-12)
    # a gesture: the curve over the note, then the bow stop (release 0.04 s) to 0
    assert np.allclose(g4.scene.vb_at([0.0, 0.1, 0.2, 0.3, 0.32, 0.34]), [0.15, 0.2, 0.25, 0.25, 0.125, 0.0])
    # a preset's fields below the note's own: f0 from the note, fb and vb from paper-fb1000
    assert f600.scene.f0 == 600.0 and f600.scene.fb_at(0.1) == 1000.0 and f600.pitch is None
    assert f600.scene.duration == pytest.approx(0.2 + 0.04 + 0.03)


def test_score_renders_notes_in_tune_at_their_starts(tmp_path, capsys, monkeypatch):
    p = tmp_path / "s.toml"
    p.write_text('[defaults]\nfb = 150.0\n[[voice]]\nname = "v"\n[[voice.note]]\nstart = 0.25\nduration = 1.0\n'
                 'pitch = "D4"\n[[voice.note]]\nstart = 0.5\nduration = 1.0\npitch = "A4"\n')
    out, stems = tmp_path / "m.wav", tmp_path / "st"
    # --dc keep: this test checks the physics (exact silence before the first start, the mass at rest after the bow
    # stop). The default 5 Hz zero-phase high-pass (wav.remove_dc) spreads each note's DC step over ~0.1 s on both
    # sides: measured -0.0083 of full scale (-41 dB re the peak) just before the onset. The DC-removed mix is
    # checked against the notes in tests/test_midi.py.
    code, so, err = run_main(["score", "--score", str(p), "--mix", str(out), "--stems", str(stems), "--method", "fdm",
                              "--dc", "keep"], capsys, monkeypatch)
    assert code == 0, err
    mix = read_wav(out)
    sr = mix.sample_rate
    assert json.loads(sf.SoundFile(str(out)).comment)["dc"] == "kept"
    assert np.all(mix.samples[:int(0.25 * sr) - 1] == 0) and np.any(mix.samples[int(0.25 * sr):int(0.26 * sr)] != 0)
    for name, pitch in (("v-001.wav", "D4"), ("v-002.wav", "A4")):
        w = read_wav(stems / name)
        # the audio-rate FDM's own dispersion is ~0.3 cents at A4: 0.5 cents is the engine, not the tuning
        assert abs(cents(f0_estimate(w.physical[:sr], sr, tail=0.5), parse_pitch(pitch))) < 0.5
        # the bow stop: the last 10 ms are silent
        assert np.max(np.abs(w.physical[-int(0.01 * sr):])) < 1e-3 * np.max(np.abs(w.physical))


@pytest.mark.parametrize("text,match", [
    ('tempo = 3\n[[voice]]\nf0 = 100.0\n', "unknown top-level key"),
    ('[defaults]\nfbb = 3\n[[voice]]\nf0 = 100.0\n', "unknown key(s) fbb"),
    ('[defaults]\nstart = 1\n[[voice]]\nf0 = 100.0\n', "unknown key(s) start"),
    ('[[voice]]\nf0 = 100.0\ncolour = "red"\n', "unknown key(s) colour"),
    ('[[voice]]\n[[voice.note]]\npitch = "A4"\nvelocity = 3\n', "unknown key(s) velocity"),
    ('[[voice]]\npitch = "A4"\nf0 = 100.0\n', "both pitch and f0"),
    ('[[voice]]\n[[voice.note]]\nfb = 100.0\nbeta = 0.1\n', "both fb and beta"),
    ('[[voice]]\nname = "a"\n[[voice]]\nname = "a"\n', "defined twice"),
    ('[[voice]]\nf0 = 100.0\nf0 = 200.0\n', "not valid TOML"),
    ('[[voice]]\n[[voice.note]]\nfb = [[0.5, 100.0], [0.2, 50.0]]\n', "times must increase"),
    ('[[voice]]\n[[voice.note]]\nvb = [[0.0, 0.2], [0.0, 0.1]]\n', "times must increase"),
    ('[[voice]]\n[[voice.note]]\nstart = -0.5\n', "start must be >= 0"),
    ('[[voice]]\n[[voice.note]]\nduration = 0.0\n', "duration must be > 0"),
    ('[[voice]]\n[[voice.note]]\npitch = "H2"\n', "German H"),
    ('[[voice]]\n[[voice.note]]\npitch = "A4"\nvb = 0.05\n', "does not speak"),
    ('[[voice]]\n[[voice.note]]\nrelease = -1.0\n', "release must be >= 0"),
    ('[[voice]]\n[[voice.note]]\npreset = "nope"\n', "unknown preset"),
    ('[[voice]]\nstart = 1.0\n[[voice.note]]\nf0 = 100.0\n', "start belongs to each"),
    ('a4 = 20.0\n[[voice]]\nf0 = 100.0\n', "a4 must be in"),
    ('[defaults]\nduration = 1.0\n', "no [[voice]]"),
    ('[[voice]]\n[[voice.note]]\nfb = [' + ", ".join(f"[{i / 100}, {100 + i}]" for i in range(200)) + ']\n',
     "too long to store in a stem"),
])
def test_bad_scores_are_one_line_exit_2_nothing_written(tmp_path, capsys, monkeypatch, text, match):
    p = tmp_path / "bad.toml"
    p.write_text(text)
    out, stems = tmp_path / "m.wav", tmp_path / "st"
    code, _, err = run_main(["score", "--score", str(p), "--mix", str(out), "--stems", str(stems), "--method", "fdm"],
                            capsys, monkeypatch)
    assert code == 2 and match in err and len(err.strip().splitlines()) == 1, err
    assert not out.exists() and not stems.exists()


def test_example_scores_load(tmp_path):
    from pathlib import Path

    ex = Path(__file__).resolve().parents[1] / "examples"
    for f in sorted(ex.glob("*.toml")) + sorted(ex.glob("*.mid")):
        assert load_score(f), f


@pytest.mark.parametrize("fields", [{"pitch": "C2", "beta": 0.637}, {"pitch": "C2", "fb": 1000.0},
                                    {"pitch": "A2", "fb": 1000.0}, {"pitch": "C2", "beta": 0.04},
                                    {"pitch": "A4", "beta": 0.159}, {"pitch": "C2", "beta": 2.5}])
def test_bow_stop_brings_the_mass_to_rest_before_the_render_ends(fields):
    """A pressed bow holds the mass aside after it stops; the tail runs until it has crept back (-60 dB)."""
    from bowsynth.engines.fdm import render_fdm
    from bowsynth.music.score import note_from_fields

    n = note_from_fields("v", {"duration": 0.4, **fields}, "test")
    u = render_fdm(n.scene).u
    assert np.max(np.abs(u[-441:])) < 1e-3 * np.max(np.abs(u))
    # a heavy bow holds the mass aside: a fixed 30 ms after the stop would have cut the note off well above that
    stop = int(round((n.hold + n.release) * 44100))
    if fields["pitch"] == "C2" and (fields.get("fb", 0) >= 1000 or fields.get("beta", 0) > 0.5):
        assert np.max(np.abs(u[stop + 1300:stop + 1400])) > 1e-2 * np.max(np.abs(u))
    assert n.scene.duration - n.hold - n.release < 0.5


def test_score_outputs_follow_the_output_rules(tmp_path, capsys, monkeypatch):
    """Stems, notes.json and the mix go through the same output machinery as `render`: a read-only stem is refused
    without --force before anything renders; with it, a FLAC mix beside WAV stems, --dc keep and a fixed --gain
    are recorded in every file."""
    p = tmp_path / "s.toml"
    p.write_text('[[voice]]\nname = "v"\n[[voice.note]]\nduration = 0.05\npitch = "A3"\n')
    stems, mix = tmp_path / "st", tmp_path / "m.flac"
    stems.mkdir()
    ro = stems / "v.wav"
    ro.write_bytes(b"precious")
    ro.chmod(0o444)
    args = ["score", "--score", str(p), "--method", "fdm", "--mix", str(mix), "--stems", str(stems)]
    code, _, err = run_main(args, capsys, monkeypatch)
    assert code == 2 and "read-only" in err and "--force" in err and len(err.strip().splitlines()) == 1, err
    assert ro.read_bytes() == b"precious" and not mix.exists() and not (stems / "notes.json").exists()
    code, _, err = run_main([*args, "--force", "--dc", "keep", "--gain", "-20"], capsys, monkeypatch)
    assert code == 0, err
    stem = read_wav(ro)
    assert stem.meta["dc"] == "kept" and math.isclose(stem.gain, 0.1)
    assert json.loads((stems / "notes.json").read_text())["dc"] == "kept"
    assert sf.info(str(mix)).format == "FLAC"
    meta = json.loads(sf.SoundFile(str(mix)).comment)
    assert meta["dc"] == "kept" and math.isclose(meta["gain"], 0.1) and meta["stems"] == "st" and meta["notes"] == 1
    code, _, err = run_main(["score", "--score", str(p), "--method", "fdm", "--mix", "-", "--stems", "-"], capsys,
                            monkeypatch)
    assert code == 2 and "not standard output" in err, err


@pytest.mark.filterwarnings("ignore::bowsynth.engines.fdm.OversampleWarning")  # the reference of the fb 12000 note
@pytest.mark.parametrize("loop", ["numpy", "core"])
def test_batched_releases_are_the_fdm_of_each_release(loop):
    """The releases of many notes run by the compiled FDM (or, the reference, as one numpy FDM batch); each equals `render_fdm` of that note's release scene (same start, scheme and Newton), for notes at several
    pitches, bow forces, speeds and release times, one of them needing the FDM oversampled, and a note without a
    release passes through untouched."""
    from bowsynth.engines.fdm import check_oversample, render_fdm
    from bowsynth.music.perform import _release_scene, finish_releases
    from bowsynth.music.score import note_from_fields
    from bowsynth.render import Played, Render

    fields = [{"pitch": "C2", "beta": 0.637, "release": 0.02}, {"pitch": "A4", "beta": 0.159, "vb": 0.3},
              {"f0": 150.0, "fb": 150.0, "vb": 0.1, "release": 0.08}, {"pitch": "G3", "fb": 12000.0},
              {"pitch": "D3", "beta": 0.1, "release": 0.0}]
    notes = [note_from_fields(f"v{i}", {"duration": 0.1, **f}, "test") for i, f in enumerate(fields)]
    rng = np.random.default_rng(3)
    sustains, before = [], []
    for n in notes:  # a stand-in sustain: any state the operator could have ended in
        sc = n.rollout_scene()
        assert sc.n_samples == n.scene.n_samples or n.release <= 0
        q, p = rng.uniform(-0.5, 0.5, sc.n_samples), rng.uniform(-0.5, 0.5, sc.n_samples)
        sustains.append(Render(sc, np.arange(sc.n_samples) / sc.sample_rate, q, p, Played("operator")))
        before.append((q.copy(), p.copy()))
    refs = [render_fdm(_release_scene(n, s)) if n.release > 0 else None for n, s in zip(notes, sustains)]
    out = finish_releases(notes, sustains, loop=loop)
    for n, (q, p), ref, r in zip(notes, before, refs, out):
        assert len(r.q) == n.scene.n_samples and r.scene is n.scene
        if n.release <= 0:
            assert np.array_equal(r.q, q) and r.method == "operator"
            continue
        hold = n.hold_samples
        assert ref.q[0] == q[hold] and abs(ref.p[0] - p[hold]) < 1e-15  # the release starts from the state at the hold
        assert np.array_equal(r.q[:hold], q[:hold]) and r.method == "operator + fdm release"
        assert np.max(np.abs(r.q[hold:] - ref.q)) < 1e-12 and np.max(np.abs(r.p[hold:] - ref.p)) < 1e-12
    assert check_oversample(_release_scene(notes[3], sustains[3]), 1, warn=False) > 1  # its own batch, oversampled


def test_a_score_note_with_an_attack_locks_to_its_held_bow_whichever_path_plays_it(tmp_path):
    """A note whose force or speed rises from 0 to the bow it holds (an attack curve) locks its windows as a plain
    note does (Scene.held_bow), both where its model plays it whole with its bow stop (v_B rising from 0 to 0.27: the
    model picked for it has a box that reaches v_B 0) and where the bow stop is handed over (v_B 0.1, the force rising
    from 0: the model picked for its sustain does not cover the stop); a crescendo note rolls free."""
    from bowsynth.music.perform import _plays_whole, render_notes

    p = tmp_path / "s.toml"
    note = '[[voice.note]]\nstart = {}\nduration = 0.8\npitch = "A3"\nvb = {}\nbeta = {}\n'
    p.write_text('[[voice]]\nname = "v"\n' + note.format(0.0, "[[0.0, 0.0], [0.05, 0.27]]", 0.15)
                 + note.format(1.0, 0.1, "[[0.0, 0.0], [0.05, 0.3]]")
                 + note.format(2.0, 0.2, "[[0.0, 0.05], [0.8, 0.3]]"))
    whole, handed, crescendo = notes = load_score(p)
    assert _plays_whole(whole) and not _plays_whole(handed)
    assert whole.rollout_scene().held_bow() is not None and crescendo.rollout_scene().held_bow() is None
    rw, rh, rc = render_notes(notes, windows="locked")
    assert rw.info.windows and rh.info.windows and not rc.info.windows
