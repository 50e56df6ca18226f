"""The compiled rollout (bowsynth._core): its own tanh, cos and sin, both loops against the torch network and the
numpy reference, per-voice failure."""

import math

import numpy as np
import pytest
import torch

from bowsynth import Scene
from bowsynth import compiled as core
from bowsynth.engines.operator.engine import render_operator
from bowsynth.engines.operator.modelfile import load_model
from bowsynth.engines.operator.rollout import (BATCH_FROM, MIN_THREAD_SAMPLES, rollout_states, voice_groups,
                                               voice_runs)
from bowsynth.engines.operator.windows import FAIL_DOMAIN, FAIL_NONFINITE, FAILURES

kernels = core.load()


def test_tanh32_matches_tanh_and_keeps_nan():
    x = np.concatenate([np.linspace(-30, 30, 200_001), [1e30, -1e30, np.inf, -np.inf]]).astype(np.float32)
    y = np.array([kernels._tanh32(v) for v in x])
    assert np.abs(y - np.tanh(x.astype(float))).max() < 5e-7
    assert np.all(np.abs(y) <= 1)
    assert math.isnan(kernels._tanh32(np.float32("nan")))


def test_cos_sin_match_libm():
    z = np.linspace(-80, 80, 100_003)
    cs = np.array([kernels._cos_sin(v) for v in z])
    assert np.abs(cs[:, 0] - np.cos(z)).max() < 1e-10
    assert np.abs(cs[:, 1] - np.sin(z)).max() < 1e-10


def torch_rollout(model, x0, n_samples, dtau, window=None):
    """The reference: the float64 torch network applied window by window (window w starting at the sample nearest
    w T, or w `window`: a locked window, windows.locked_window), its end state seeding the next."""
    net = model.net.double()
    try:
        spw = (float(net.window) if window is None else window) / dtau
        x = torch.tensor(x0, dtype=torch.float64)
        out, start, w = [], 0, 0
        with torch.no_grad():
            while start < n_samples:
                n = int(math.floor((w + 1) * spw + 0.5)) - start
                traj = net(x, torch.arange(n + 1, dtype=torch.float64) * dtau)  # (B, n + 1, 2)
                out.append(traj[:, :n])
                x = traj[:, n]
                start, w = start + n, w + 1
        return torch.cat(out, dim=1).numpy()[:, :n_samples]
    finally:
        model.net.float()


def test_window_starts_stay_on_multiples_of_the_window():
    spw = 220.5  # f0 200 at 44.1 kHz, window 2 pi
    ends = np.array([kernels._window_end(w, spw) for w in range(1000)])
    assert set(np.diff(ends)) == {220, 221}
    assert np.abs(ends - np.arange(1, 1001) * spw).max() <= 0.5
    assert set(np.diff([kernels._window_end(w, 441.0) for w in range(100)])) == {441}


@pytest.mark.parametrize("f0", [100.0, 200.0], ids=["441-sample-windows", "220-and-221"])
@pytest.mark.parametrize("loop,voices", [("core-voices", 1), ("core-voices", BATCH_FROM + 1),
                                         ("core-batch", BATCH_FROM + 1), ("core", 1), ("core", BATCH_FROM + 1)],
                         ids=["voice-loop", "voice-loop-many", "batch-loop", "groups-one", "groups"])
def test_rollout_follows_the_torch_network(tiny_model, loop, voices, f0):
    m = load_model(tiny_model)
    sc = Scene(fb=f0, f0=f0)
    dtau = sc.omega / sc.sample_rate
    d = m.domain
    x0 = np.stack([np.linspace(0.4 * d.q_lo, 0.4 * d.q_hi, voices), np.linspace(0.3 * d.p_hi, 0.3 * d.p_lo, voices)], 1)
    n = 5 * 441 * 100 // int(f0)  # five windows
    ref = torch_rollout(m, x0, n, dtau)
    q, p, fail = rollout_states(m, x0, n, dtau, check_domain=False, loop=loop)
    assert np.all(fail[:, 0] == -1)
    scale = np.abs(ref).max()
    # float32 network against float64 torch, over five windows
    assert np.abs(q - ref[..., 0]).max() < 2e-5 * scale
    assert np.abs(p - ref[..., 1]).max() < 2e-5 * scale


@pytest.mark.parametrize("loop,voices", [("core-voices", 3), ("core-batch", BATCH_FROM + 2), ("core", 6)],
                         ids=["voice-loop", "batch-loop", "groups"])
def test_one_voice_failing_stops_only_that_voice(tiny_model, loop, voices):
    m = load_model(tiny_model)
    sc = Scene(fb=100)
    x0 = np.zeros((voices, 2))
    x0[1] = [np.nan, 0.0]  # non-finite from the first window on
    q, p, fail = rollout_states(m, x0, 3000, sc.omega / sc.sample_rate, check_domain=False, loop=loop)
    assert tuple(fail[1]) == (0, kernels.FAIL_NONFINITE) and np.all(np.isnan(q[1]))
    others = np.delete(np.arange(voices), 1)
    assert np.all(fail[others, 0] == -1) and np.all(np.isfinite(q[others])) and np.all(np.isfinite(p[others]))
    assert (kernels.FAIL_NONFINITE, kernels.FAIL_DOMAIN) == (FAIL_NONFINITE, FAIL_DOMAIN)  # the codes agree
    assert FAIL_NONFINITE in FAILURES and FAIL_DOMAIN in FAILURES


def test_voices_split_over_threads_roll_as_on_one(tiny_model):
    """A render's voices in groups by pitch over several threads (whole groups, taken from one queue as each thread
    is free; the voices' inputs put in the groups' order, so a group of rows that are not neighbours is a slice)
    give the bits of one thread, failures included, in whichever group the failing voice falls; and each voice as
    the same loop gives it alone, to float32 rounding."""
    m = load_model(tiny_model)
    voices, n = 9, 40_000
    f0 = np.array([400.0, 90.0, 250.0, 130.0, 330.0, 170.0, 210.0, 110.0, 290.0])  # groups of rows far apart
    dtau = 2 * np.pi * f0 / 44_100
    x0 = np.zeros((voices, 2))
    x0[6] = [np.nan, 0.0]  # fails at once
    x0[2] = [m.domain.q_hi * 50, 0.0]  # starts far outside the trained states: a domain failure
    groups = voice_groups(2 * np.pi / dtau)
    assert any(g.max() - g.min() + 1 > len(g) for g in groups)  # the inputs are put in the groups' order
    runs = voice_runs(np.array([(n * (1 + 245 * dtau[g] / (2 * np.pi))).sum() for g in groups]), 2)
    assert len(runs) == 2  # the work is split, else this test tests nothing
    one = rollout_states(m, x0, n, dtau, loop="core-1")  # the same groups, on one thread
    two = rollout_states(m, x0, n, dtau, loop="core")
    for a, b in zip(one, two):
        assert np.array_equal(a, b, equal_nan=True)
    assert tuple(two[2][6]) == (0, FAIL_NONFINITE) and two[2][2, 0] >= 0 and two[2][2, 1] == FAIL_DOMAIN
    assert np.all(two[2][[0, 1, 3, 4, 5, 7, 8], 0] == -1)
    for v in (0, 5):
        q1, p1, _ = rollout_states(m, x0[v:v + 1], n, dtau[v], loop="core-voices")
        assert np.abs(q1[0] - two[0][v]).max() < 1e-4 * np.abs(q1).max()


@pytest.mark.parametrize("work,n_threads", [([1e6] * 10, 2), ([1e6] * 10, 3), ([5e5, 1e3, 1e3, 5e5], 2),
                                            ([1e6, 1.0], 2), ([4e4] * 4, 8), ([1e6], 4), ([2e5] * 5, 8)])
def test_voice_runs_cover_the_voices_in_balanced_runs(work, n_threads):
    work = np.array(work)
    runs = voice_runs(work, n_threads)
    assert runs[0][0] == 0 and runs[-1][1] == len(work)
    assert all(a < b for a, b in runs) and all(r[1] == s[0] for r, s in zip(runs, runs[1:]))
    assert len(runs) <= min(n_threads, len(work))
    assert len(runs) == 1 or all(work[a:b].sum() >= MIN_THREAD_SAMPLES for a, b in runs)
    if len(runs) > 1:  # no run holds more than a fair share plus one voice
        assert max(work[a:b].sum() for a, b in runs) <= work.sum() / len(runs) + work.max()


def test_batched_render_finishes_a_stray_voice_with_the_fdm(tiny_model, tmp_path):
    m = load_model(tiny_model)
    d = m.domain
    # a thin domain: voices starting on it leave it within a few windows
    d.mask[:] = False
    d.mask[d.mask.shape[0] // 2 - 1: d.mask.shape[0] // 2 + 1, :] = True
    d.q_lo, d.q_hi = -1e-3, 1e-3
    scenes = [Scene(fb=100, duration=0.1), Scene(fb=100, duration=0.1, q0=-2e-5)]
    from bowsynth.errors import DomainError

    with pytest.raises(DomainError, match="voice 1: the rollout left"):
        render_operator(scenes, model=m)
    renders = render_operator(scenes, model=m, fallback="fdm")
    for r in renders:
        assert r.method == "operator+fdm" and "finished with the FDM" in r.info.notes[0]
        assert len(r.q) == r.scene.n_samples  # what the continuation holds: tests/test_fallback.py


@pytest.mark.parametrize("loop,voices", [("numpy", 5), ("core-voices", 3), ("core-batch", BATCH_FROM + 1),
                                         ("core", BATCH_FROM + 1)],
                         ids=["numpy-loop", "core-voice-loop", "core-batch-loop", "core-groups"])
def test_voices_at_different_pitches_roll_in_one_batch(loop, voices):
    from bowsynth.engines.operator.choose import SHIPPED_DIR

    m = load_model(SHIPPED_DIR / "paper-fb100.safetensors")
    f0 = 100 * 2 ** (np.arange(voices) / 7)  # windows of 441 samples down to ~240, mostly not whole numbers
    dtau = 2 * np.pi * f0 / 44100
    x0 = np.stack([np.linspace(0, 0.1, voices), np.linspace(0, -0.05, voices)], 1)
    n = 3000
    q, p, fail = rollout_states(m, x0, n, dtau, check_domain=False, loop=loop)
    assert np.all(fail[:, 0] == -1)
    for b in range(voices):
        ref = torch_rollout(m, x0[b:b + 1], n, dtau[b])[0]
        scale = np.abs(ref).max()
        assert np.abs(q[b] - ref[:, 0]).max() < 2e-5 * scale, b
        assert np.abs(p[b] - ref[:, 1]).max() < 2e-5 * scale, b
        q1, p1, _ = rollout_states(m, x0[b:b + 1], n, dtau[b], check_domain=False, loop="numpy")
        assert np.abs(q[b] - q1[0]).max() < 1e-5 * scale and np.abs(p[b] - p1[0]).max() < 1e-5 * scale


def test_numpy_loop_stops_a_failing_voice_like_the_compiled_ones(tiny_model):
    m = load_model(tiny_model)
    sc = Scene(fb=100)
    x0 = np.zeros((4, 2))
    x0[2] = [np.nan, 0.0]
    d = m.domain
    x0[3] = [d.q_hi * 0.99, 0.0]  # near the edge of the box: may leave it
    runs = [rollout_states(m, x0, 3000, sc.omega / sc.sample_rate, loop=lp) for lp in ("numpy", "core")]
    (qa, pa, fa), (qb, pb, fb) = runs
    assert np.array_equal(fa, fb) and tuple(fa[2]) == (0, kernels.FAIL_NONFINITE)
    ok = np.isfinite(qb)
    assert np.array_equal(ok, np.isfinite(qa))
    assert np.abs(qa[ok] - qb[ok]).max() < 1e-5 and np.abs(pa[ok] - pb[ok]).max() < 1e-5


def test_trunk_features_interpolated_for_many_pitches_match_the_network():
    from bowsynth.engines.operator import npnet
    from bowsynth.engines.operator.basis import DIRECT_POINTS, numpy_operator
    from bowsynth.engines.operator.choose import SHIPPED_DIR

    for name in ("paper-fb10", "paper-fb100", "paper-fb1000"):
        op = numpy_operator(load_model(SHIPPED_DIR / f"{name}.safetensors"))
        f0 = 100 * 2 ** (np.arange(40) / 40)
        offsets = [np.arange(442 * 100 // int(f) + 2) * (2 * np.pi * f / 44100) / op.window for f in f0]
        assert sum(map(len, offsets)) > DIRECT_POINTS  # the interpolated path
        for s, f in zip(offsets, op.trunk_features(offsets)):
            direct = npnet.trunk_features(op._w, op.cfg, s)
            assert np.abs(f - direct).max() < 1e-7 * np.abs(direct).max()  # float32 rounding is 6e-8


@pytest.mark.parametrize("loop,voices", [("numpy", 2), ("core-voices", 1), ("core-batch", BATCH_FROM + 1),
                                         ("core", 5)],
                         ids=["numpy", "voice-loop", "batch-loop", "groups"])
def test_rest_linearised_flow_rolls_like_the_torch_network(tiny_rest_model, loop, voices):
    """A model whose linear part is the flow linearised at rest (damped rotation about the static deflection, in
    the window bases and the end states): every loop follows the torch network, at a pitch whose windows hold 220
    and 221 samples."""
    m = load_model(tiny_rest_model)
    assert m.cfg.rest_linear and m.weights["lin"].shape == (2,)
    sc = Scene(f0=200.0)
    d = m.domain
    x0 = np.stack([np.linspace(0.4 * d.q_lo, 0.4 * d.q_hi, voices), np.linspace(0.3 * d.p_hi, 0.3 * d.p_lo, voices)], 1)
    n = 5 * 221
    ref = torch_rollout(m, x0, n, sc.dtau)
    q, p, fail = rollout_states(m, x0, n, sc.dtau, check_domain=False, loop=loop)
    assert np.all(fail[:, 0] == -1)
    scale = np.abs(ref).max()
    assert np.abs(q - ref[..., 0]).max() < 2e-5 * scale
    assert np.abs(p - ref[..., 1]).max() < 2e-5 * scale


def test_the_linear_parts_are_the_exact_flows(tiny_rest_model):
    """The torch network's linear part and its derivative: the rotation for a plain model; for a rest-linearised
    one exp(A tau) about the rest state (against scipy's expm), whose derivative is A (x - x_s)."""
    from scipy.linalg import expm

    from bowsynth import physics

    m = load_model(tiny_rest_model)
    net = m.net.double()
    try:
        d, qs = (float(v) for v in net.lin)
        assert (d, qs) == pytest.approx(physics.rest_linearisation(0.815, 0.3, 100.0))
        assert d < 0  # the bow drives the mass out of rest
        tau = torch.linspace(0, 6.0, 13, dtype=torch.float64)
        x0 = torch.tensor([[0.3, -0.2], [qs, 0.0]], dtype=torch.float64)
        lin, dlin = net.flow(x0, tau)
        A = np.array([[0.0, 1.0], [-1.0, -d]])
        for i, t in enumerate(tau.numpy()):
            want = np.array([qs, 0.0]) + expm(A * t) @ (x0[0].numpy() - [qs, 0.0])
            np.testing.assert_allclose(lin[0, i].numpy(), want, atol=1e-12)
            np.testing.assert_allclose(dlin[0, i].numpy(), A @ (want - [qs, 0.0]), atol=1e-12)
        np.testing.assert_allclose(lin[1].numpy(), np.tile([qs, 0.0], (13, 1)), atol=1e-15)  # rest stays at rest
    finally:
        m.net.float()


def test_the_trunk_grid_is_kept_on_disk_and_a_bad_copy_is_recomputed(tmp_path, monkeypatch):
    """The grid a score's bases and the live voices interpolate: computed once, then read by the next process; a
    truncated, edited, non-finite or FIFO copy is never trusted (recomputed and replaced); no cache, no file."""
    import os

    from bowsynth.engines.operator import npnet
    from bowsynth.engines.operator.basis import TRUNK_H, TRUNK_POINTS, trunk_grid
    from bowsynth.engines.operator.choose import SHIPPED_DIR

    monkeypatch.setenv("BOWSYNTH_CACHE", str(tmp_path))
    path = SHIPPED_DIR / "paper-fb100.safetensors"
    g = trunk_grid(load_model(path))
    files = list(tmp_path.glob("trunk-*.npy"))
    assert len(files) == 1 and g.shape == (TRUNK_POINTS, 2, load_model(path).cfg.k)
    s = np.array([-TRUNK_H, 0.0, 0.5, 1.9])
    direct = npnet.trunk_features(load_model(path).weights, load_model(path).cfg, s)
    assert np.abs(g[[0, 1]] - direct[:2]).max() < 1e-12 * np.abs(direct).max() and not g.flags.writeable
    # the next process's model reads the file: the same array, not a new evaluation (16 rows checked)
    real = npnet.trunk_features
    monkeypatch.setattr(npnet, "trunk_features", lambda w, c, s: real(w, c, s) if len(s) <= 16 else pytest.fail(
        "evaluated again"))
    assert np.array_equal(trunk_grid(load_model(path)), g)
    monkeypatch.undo()
    monkeypatch.setenv("BOWSYNTH_CACHE", str(tmp_path))
    f = files[0]
    good = f.read_bytes()
    bad = g.copy()
    bad[5, 0, 0] = np.nan
    np.save(tmp_path / "nan.npy", bad)
    for damage in (good[:len(good) // 2], good[:200] + b"\0" * (len(good) - 200), (tmp_path / "nan.npy").read_bytes()):
        f.write_bytes(damage)
        again = trunk_grid(load_model(path))
        assert np.array_equal(again, g) and f.read_bytes() == good
    f.unlink()
    os.mkfifo(f)  # a FIFO is not read (it would block): recomputed, and the FIFO replaced by the file
    assert np.array_equal(trunk_grid(load_model(path)), g) and f.read_bytes() == good
    f.unlink()
    monkeypatch.setenv("BOWSYNTH_CACHE", "off")
    assert np.array_equal(trunk_grid(load_model(path)), g) and not f.exists()
