"""Many voices: a batched rollout equals the voices rendered one by one; scores and mixes from the CLI."""

import numpy as np

from bowsynth import Scene
from bowsynth.model import load_model
from bowsynth.rollout import render_operator
from bowsynth.score import load_score
from bowsynth.wav import read_wav
from conftest import run_main


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
    from bowsynth.rollout import BATCH_FROM, rollout_states

    m = load_model(tiny_model)
    sc = Scene(fb=100)
    x0 = np.array([[0.001 * i, -0.002 * i] for i in range(BATCH_FROM)])
    dt = sc.omega / sc.sample_rate
    q, p, fail = rollout_states(m, x0, 2000, dt, check_domain=False)
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
    assert mix.meta is None and np.max(np.abs(mix.samples)) > 0.5 and np.all(np.isfinite(mix.samples))
    code, out, err = run_main(["score", "--presets", "paper-fb10,paper-fb100", "--method", "fdm", "-d", "0.05",
                               str(tmp_path / "p")], capsys, monkeypatch)
    assert code == 0 and sorted(p.name for p in (tmp_path / "p").iterdir()) == ["notes.json", "paper-fb10.wav",
                                                                               "paper-fb100.wav"]


def test_voices_without_a_named_model_share_one_rollout(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # no ./models: the shipped paper-fb100 covers both (same F_B / w, other pitches)
    renders = render_operator([Scene(fb=100, duration=0.02), Scene(fb=150, f0=150, duration=0.02, q0=0.001)])
    assert [r.info["batched"] for r in renders] == [2, 2]
    assert all(r.info["model_path"].endswith("paper-fb100.safetensors") for r in renders)


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
    assert out.count("finished with the FDM") == 2
    assert sorted(p.name for p in (tmp_path / "v").iterdir()) == ["paper-fb100-2.wav", "paper-fb100.wav"]
    assert np.all(np.isfinite(read_wav(tmp_path / "v" / "paper-fb100-2.wav").samples))
