"""Hard cases: long renders of the shipped models, high force, extreme bow speed and friction shape."""

import warnings

import numpy as np
import pytest

from bowsynth import Scene, render_fdm
from bowsynth.metrics import cents, f0_estimate
from bowsynth.rollout import SHIPPED_DIR, render_operator, rollout_states
from bowsynth.model import load_model

SHIPPED = sorted(p for p in SHIPPED_DIR.glob("*.safetensors") if not p.name.endswith(".ckpt.safetensors"))


@pytest.mark.parametrize("path", SHIPPED, ids=[p.stem for p in SHIPPED])
def test_shipped_model_30s_finite_in_domain_on_pitch(path):
    m = load_model(path)
    sc = Scene(**{**m.meta.scene, "duration": 30.0})
    r = render_operator(sc, model=m)  # raises if the rollout leaves the domain or turns non-finite
    assert np.all(np.isfinite(r.q)) and np.all(np.isfinite(r.p))
    assert np.all(m.domain.contains(r.q[::97], r.p[::97]))
    ref = render_fdm(sc.replace(duration=5.0), oversample=8)
    # pitch of the last seconds of the 30 s operator render against the FDM's steady state
    f_op = f0_estimate(r.q[-5 * sc.sample_rate:], sc.sample_rate, tail=1.0)
    f_ref = f0_estimate(ref.q, sc.sample_rate)
    assert abs(cents(f_op, f_ref)) < 1.0


@pytest.mark.parametrize("path", SHIPPED, ids=[p.stem for p in SHIPPED])
def test_random_states_in_domain_roll_out_finite(path):
    m = load_model(path)
    d = m.domain
    rng = np.random.default_rng(1)
    x = rng.uniform([d.q_lo, d.p_lo], [d.q_hi, d.p_hi], size=(4000, 2))
    x = x[d.contains(x[:, 0], x[:, 1])][:64]
    sc = Scene(**m.meta.scene)
    q, p, fail = rollout_states(m, x, 2 * sc.sample_rate, sc.omega / sc.sample_rate, check_domain=False)
    assert np.all(fail[:, 0] == -1), fail
    assert np.all(np.isfinite(q)) and np.all(np.isfinite(p))


@pytest.mark.parametrize("fb", [2000.0, 5000.0, 10_000.0])
def test_fdm_high_force_oversamples_and_stays_finite(fb):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = render_fdm(Scene(fb=fb, duration=0.2))
    assert np.all(np.isfinite(r.p)) and r.info["oversample"] >= (2 if fb >= 10_000 else 1)
    assert np.abs(r.p).max() < 50


@pytest.mark.parametrize("vb,a", [(0.01, 100.0), (1.0, 100.0), (0.2, 10.0), (0.2, 1000.0), (1.0, 1000.0)])
def test_fdm_extreme_bow_speed_and_friction_shape(vb, a):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = render_fdm(Scene(fb=1000, vb=vb, a=a, duration=0.3))
    assert np.all(np.isfinite(r.q)) and np.all(np.isfinite(r.p))
    # energy is bounded: the bow can't push the mass much past a few times its own speed
    assert np.abs(r.p).max() < 20 * vb + 10
