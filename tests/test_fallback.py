"""--fallback fdm: the FDM continuation of a stray voice is an FDM render from the operator's state at the hand-off
(sample at - 1, `at` the first sample of the window where the rollout left), and the samples before it are the
operator's; single voices, both rollout loops, and through the CLI."""

import subprocess
import sys

import numpy as np
import pytest

from bowsynth import Scene, load_model, render_fdm, render_operator
from bowsynth.engines.operator.rollout import BATCH_FROM, rollout_states
from bowsynth.io.audio import read_wav


def thin(model):
    """Shrink the model's domain to a thin strip around q = 0, so renders from near rest leave it within a few
    windows (the weights, and so the rollout up to the hand-off, are unchanged). The strip is the mask's (the
    rollout's check of each window's start); the box stays, so the engine's check of every sample (BOX_SLACK) does
    not fire first."""
    d = model.domain
    d.mask[:] = False
    d.mask[d.mask.shape[0] // 2 - 1: d.mask.shape[0] // 2 + 1, :] = True
    return model


def check_continuations(model, scenes, renders) -> list[int]:
    """Each render (of a scene, rolled out together with fallback fdm) = the operator up to its hand-off, then the FDM
    from the operator's state there. Returns each voice's `at`."""
    sc0 = scenes[0]
    dtau = sc0.omega / sc0.sample_rate
    x0 = [[sc.q0, sc.p0] for sc in scenes]
    n = sc0.n_samples
    # the same rollout (same loop, same batch: float32 rounding depends on both), with and without the domain check
    _, _, fail = rollout_states(model, x0, n, dtau)
    q_op, p_op, fail_off = rollout_states(model, x0, n, dtau, check_domain=False)
    assert np.all(fail_off[:, 0] == -1)
    ats = []
    for i, (sc, r) in enumerate(zip(scenes, renders)):
        at = int(fail[i, 0])
        assert 1 < at < n - 100, at  # the voice left the domain inside the render, after its first window
        start = at - 1
        np.testing.assert_array_equal(r.q[:start], q_op[i, :start])
        np.testing.assert_array_equal(r.p[:start], p_op[i, :start])
        cont = render_fdm(sc.replace(q0=float(q_op[i, start]), p0=float(p_op[i, start]),
                                     duration=(n - start) / sc.sample_rate))
        np.testing.assert_array_equal(r.q[start:], cont.q.astype(r.q.dtype))
        np.testing.assert_array_equal(r.p[start:], cont.p.astype(r.p.dtype))
        # and it is neither the FDM from the scene's start nor the operator's own continuation
        assert np.abs(r.p[start:] - render_fdm(sc).p[start:]).max() > 1e-4 * np.abs(cont.p).max()
        assert np.abs(r.p[start + 50:] - p_op[i, start + 50:]).max() > 1e-6 * np.abs(cont.p).max()
        ats.append(at)
    return ats


def test_single_voice_continuation_is_the_fdm_from_the_hand_off_state(tiny_model):
    m = thin(load_model(tiny_model))
    sc = Scene(fb=100, duration=0.1)
    r = render_operator(sc, model=m, fallback="fdm")
    [at] = check_continuations(m, [sc], [r])
    assert r.method == "operator+fdm" and f"t = {at / sc.sample_rate:.4f} s" in r.info.notes[0]


@pytest.mark.parametrize("voices", [2, BATCH_FROM + 1], ids=["voice-loop", "batch-loop"])
def test_batched_continuations_are_the_fdm_from_each_hand_off_state(tiny_model, voices):
    m = thin(load_model(tiny_model))
    scenes = [Scene(fb=100, duration=0.1, q0=-3e-6 * i, p0=1e-4 * i) for i in range(voices)]
    renders = render_operator(scenes, model=m, fallback="fdm")
    check_continuations(m, scenes, renders)
    assert all(r.method == "operator+fdm" for r in renders)


def test_cli_fallback_writes_the_continuation(tmp_path, tiny_model):
    m = thin(load_model(tiny_model))
    small = tmp_path / "small.safetensors"
    m.save(small)
    wav = tmp_path / "f.wav"
    r = subprocess.run([sys.executable, "-m", "bowsynth", "render", "--fb", "100", "-d", "0.1", "--signal", "p",
                        "--model", str(small), "--fallback", "fdm", str(wav)], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stderr
    assert "finished with the FDM" in r.stdout
    sc = Scene(fb=100, duration=0.1)
    expect = render_operator(sc, model=load_model(small), fallback="fdm")
    info = read_wav(wav)
    from bowsynth.io.audio import remove_dc

    assert info.dc_removed  # the default; the continuation is compared through the same filter
    want = remove_dc(expect.p, sc.sample_rate)
    # the WAV stores the signal scaled to its peak in float32 (wav.py); compare at that precision
    np.testing.assert_allclose(info.physical, want, rtol=0, atol=1e-6 * np.abs(want).max())


def test_a_rollout_whose_samples_leave_the_trained_box_is_stopped_though_its_window_starts_stay_inside(monkeypatch):
    """paper-fb1000 (stick-slip, trained at 100 Hz) at 440 Hz on the output grid's windows (what renders did before
    stick-slip voices were computed on whole windows: forced here): its window starts stay in the domain while the
    samples between them break out of the stick-slip cycle (p to 1.6, the truth's peak is 0.26): refused, or finished
    by the FDM with a note. At 300 Hz it plays."""
    from pathlib import Path

    import bowsynth
    from bowsynth.engines.operator import engine
    from bowsynth.engines.operator.engine import BOX_SLACK
    from bowsynth.errors import DomainError

    monkeypatch.setattr(engine, "needs_whole_windows", lambda domain, beta_max=None: False)
    m = load_model(bowsynth.shipped("models") / "paper-fb1000.safetensors")
    d = m.domain

    def scene(f0):
        return Scene(f0=f0, fb=d.beta * 2 * np.pi * f0, vb=d.vb, a=d.a, duration=1.0)

    ok = render_operator(scene(300.0), model=m)
    assert ok.info.notes == [] and np.max(ok.p) < d.p_hi
    with pytest.raises(DomainError, match="left the model's trained states"):
        render_operator(scene(440.0), model=m)
    r = render_operator(scene(440.0), model=m, fallback="fdm")
    assert any("finished with the FDM" in n for n in r.info.notes)
    assert np.max(r.p) < d.p_hi + BOX_SLACK * (d.p_hi - d.p_lo)
    # the FDM from the hand-over settles on the truth's stick-slip cycle (its phase is the hand-over's own)
    truth = render_fdm(scene(440.0), oversample=4)
    span = d.p_hi - d.p_lo
    assert abs(np.max(r.p[-4410:]) - np.max(truth.p[-4410:])) < 0.02 * span
    assert abs(np.min(r.p[-4410:]) - np.min(truth.p[-4410:])) < 0.02 * span
