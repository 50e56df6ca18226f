import math
import warnings

import numpy as np
import pytest

from bowsynth import Scene, SceneError, physics, render_fdm
from bowsynth.engines.fdm import OversampleWarning, fdm_batch, run_fdm_raw


def test_fb0_is_harmonic_oscillator_to_second_order():
    s = Scene(fb=0.0, q0=0.1, p0=-0.05, duration=0.05)
    errs = []
    for os_ in (1, 2, 4):
        r = render_fdm(s, oversample=os_)
        q_ex, p_ex = physics.linear_flow(s.q0, s.p0, s.omega * r.t)
        errs.append(max(np.abs(r.q - q_ex).max(), np.abs(r.p - p_ex).max()))
    assert errs[0] < 1e-3 * math.hypot(s.q0, s.p0)
    assert 3.6 < errs[0] / errs[1] < 4.4 and 3.6 < errs[1] / errs[2] < 4.4


@pytest.mark.parametrize("fb", [100.0, 1000.0])
def test_second_order_convergence(fb):
    s = Scene(fb=fb, duration=0.03)
    ref = render_fdm(s, oversample=128)
    errs = [np.abs(render_fdm(s, oversample=o).p - ref.p).max() for o in (2, 4, 8)]
    for e1, e2 in zip(errs, errs[1:]):
        assert 3.5 < e1 / e2 < 4.5


def test_initial_state_exact_and_u_is_q_over_omega():
    s = Scene(fb=100, q0=0.03, p0=0.1, duration=0.01, f0=150)
    r = render_fdm(s)
    assert r.q[0] == s.q0 and r.p[0] == s.p0
    np.testing.assert_allclose(r.u, r.q / (2 * math.pi * 150))
    assert r.t.dtype == np.float64 and len(r.t) == s.n_samples


def test_reproduces_authors_matlab_render(anchors):
    d = np.load(anchors / "paper_fdm_fb50_44k.npz")
    q_ref, p_ref = d["q"], d["p"]
    w, k = 2 * math.pi * 100, 1 / 44100
    # their index 0 and 1 both hold u = 0: q_ref[n + 1] = w u^n of a scheme started from u^{-1} = u^0 = 0
    u, _ = run_fdm_raw(0.0, 0.0, len(q_ref) - 1, 1, k, w, 50.0, 0.2, 100.0)
    q = w * u
    assert np.abs(q - q_ref[1:]).max() / np.abs(q_ref).max() < 1e-5
    p = np.diff(q) / (w * k)  # their p is staggered
    assert np.abs(p - p_ref[1:len(p) + 1]).max() / np.abs(p_ref).max() < 1e-4


@pytest.mark.parametrize("loop", ["core", "numpy"])
def test_batch_agrees_with_single_voice(loop):
    rng = np.random.default_rng(0)
    q0, p0 = rng.uniform(-0.3, 0.3, 6), rng.uniform(-0.3, 0.3, 6)
    s = Scene(fb=1000, duration=0.004)
    q, p = fdm_batch(q0, p0, s.n_samples, 1, 1 / s.sample_rate, s.omega, s.fb, s.vb, s.a, loop=loop)
    for i in range(len(q0)):
        r = render_fdm(s.replace(q0=q0[i], p0=p0[i]))
        assert np.abs(r.q - q[i]).max() < 1e-12 and np.abs(r.p - p[i]).max() < 1e-12


def _numpy_exp_is_libm() -> bool:
    """Does numpy's exp give the C library's bits, which the compiled loops use? On most CPUs it does; on AVX-512
    ones numpy computes it in its own SIMD code, an ulp off on ~5 % of arguments (46k of 1M in [-50, 1], measured on
    an AVX-512 Xeon with numpy 2.4), and the numpy reference then parts from the compiled loop in the last bits."""
    x = np.linspace(-50.0, 1.0, 20001)
    return np.array_equal(np.exp(x), np.array([math.exp(v) for v in x]))


def test_the_batchs_two_loops_agree_to_the_bit_over_pitches_and_bows():
    """Training data's batch: states at their own pitch, force and speed (stick-slip among them), oversampled; the
    compiled rows (over threads) and the vectorised numpy reference give the same numbers (to the bit where numpy's
    exp is the C library's), progress to the end."""
    rng = np.random.default_rng(1)
    n = 300
    q0, p0 = rng.uniform(-0.5, 0.5, n), rng.uniform(-0.5, 0.5, n)
    w = rng.uniform(400.0, 6000.0, n)
    fb, vb = w * rng.uniform(0.02, 2.0, n), rng.uniform(0.0, 0.3, n)
    k = 0.9 * physics.max_stable_step(float(fb.max()), 100.0)
    seen = []
    a = fdm_batch(q0, p0, 200, 3, k, w, fb, vb, 100.0, loop="numpy")
    b = fdm_batch(q0, p0, 200, 3, k, w, fb, vb, 100.0, on_progress=seen.append)
    assert np.all(np.isfinite(b[1]))
    if _numpy_exp_is_libm():
        assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    else:  # the same steps with an exponential an ulp apart: equal to rounding (measured 2e-14), not to the bit
        assert np.abs(a[0] - b[0]).max() < 1e-12 and np.abs(a[1] - b[1]).max() < 1e-12
    assert seen and seen[-1] == 1.0 and seen == sorted(seen)


def test_uniqueness_bound_raises_oversampling():
    s = Scene(fb=10_000, duration=0.01)
    assert 1 / 44100 > physics.max_stable_step(10_000, 100)
    with pytest.warns(OversampleWarning, match="oversampling raised from 1 to 2"):
        r = render_fdm(s)
    assert r.info.oversample == 2 and np.all(np.isfinite(r.p))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert render_fdm(s, oversample=4).info.oversample == 4
    with pytest.raises(SceneError, match="limit is x1024"):
        render_fdm(Scene(fb=1e6, a=1e6, duration=0.01))
    with pytest.raises(ValueError, match="uniqueness"):
        fdm_batch([0.0], [0.0], 3, 1, 1 / 44100, s.omega, 10_000, 0.2, 100)


def test_energy_balance():
    # dE/dt = -F_B phi(p - v_B) p: integrate the bow's power and compare with the energy change
    s = Scene(fb=100, duration=0.05)
    r = render_fdm(s, oversample=16)
    e = physics.energy(r.q, r.p)
    pw = physics.friction_power(r.p, s.fb, s.vb, s.a)
    work = np.concatenate([[0], np.cumsum(0.5 * (pw[1:] + pw[:-1]) / s.sample_rate)])
    assert np.abs(e - e[0] - work).max() < 1e-3 * e.max()


def test_paper_operator_scores_reproduced(anchors):
    """Our FDM x100 and NMSE score the paper's own rollouts as the anchors README says they score."""
    from bowsynth.analysis.bench import bench_paper_anchors

    rows = {r["case"]: r for r in bench_paper_anchors(anchors)}
    expect = {"paper_deeponet_fb10": (1.4e-4, 2.5e-4), "paper_deeponet_fb100": (8.1e-7, 9.5e-7),
              "paper_deeponet_hybrid_fb1000": (6.9e-3, 1.72)}
    for case, (e01, e05) in expect.items():
        assert rows[case]["nmse_p_0.1s"] == pytest.approx(e01, rel=0.15), case
        assert rows[case]["nmse_p_0.5s"] == pytest.approx(e05, rel=0.15), case
