"""A held note must speak where the physics grows it (engines/operator/onset.mute_from): a model whose note sits at
its rest point there (a stick-slip tile at the playing space's corner, F_B / w 2, v_B 0.28) is stopped like a rollout
that leaves its states, instead of playing a silent wrong note."""

import math
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bowsynth import DomainError, Scene, physics
from bowsynth.api import render
from bowsynth.engines.operator.onset import MUTE_SAFETY, mute_from

from conftest import refined_from, shipped_pick


def held(f0, beta, vb, seconds):
    return Scene(f0=f0, fb=beta * 2 * math.pi * f0, vb=vb, duration=seconds)


def test_a_silent_p_is_caught_after_the_physics_would_have_spoken_and_the_truth_is_not():
    sc = held(110.0, 2.0, 0.28, 1.0)
    at = mute_from(sc, np.zeros(sc.n_samples))
    offset = physics.rest_linearisation(sc.beta, sc.vb, sc.a)[1]
    t_speak = math.log((sc.vb - physics.vb_stop(sc.a)) / offset) / physics.onset_rate(sc.beta, sc.vb, sc.a) / sc.omega
    assert at is not None and at / sc.sample_rate == pytest.approx(MUTE_SAFETY * t_speak, abs=2 / sc.sample_rate)
    assert mute_from(sc, render(sc, engine="fdm", oversample=8).p) is None
    # no verdict where the physics lets the mass rest (a bow below vb_stop), where the bow moves, or too soon to tell
    assert mute_from(held(110.0, 2.0, 0.06, 1.0), np.zeros(44100)) is None
    moving = Scene(f0=110.0, fb=[(0.0, 1000.0), (1.0, 1300.0)], vb=0.28, duration=1.0)
    assert mute_from(moving, np.zeros(moving.n_samples)) is None
    short = held(110.0, 2.0, 0.28, 0.08)
    assert mute_from(short, np.zeros(short.n_samples)) is None


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.floats(65.0, 880.0), st.floats(0.02, 2.0), st.floats(0.075, 0.3))
def test_the_truth_always_speaks_where_the_check_would_ask_it_to(f0, beta, vb):
    sc = held(f0, beta, vb, 0.5)
    assert mute_from(sc, render(sc, engine="fdm", oversample=4).p) is None


def test_the_corner_note_is_refused_in_one_line_and_finished_by_the_fdm_on_request(tmp_path):
    """The model the default pick there (which speaks) was refined from, asked for by its file."""
    sc = held(110.0, 2.0, 0.28, 1.0)
    m = refined_from(shipped_pick(sc))
    assert m.failure is None and m.covers(sc), m.path
    with pytest.raises(DomainError, match="still silent, though its bow drives the mass"):
        render(sc, engine="operator", model=m)
    r = render(sc, engine="operator", model=m, fallback="fdm")
    assert r.method.fdm_fallback and np.ptp(r.p[-4410:]) > 1.0  # the truth's stick-slip cycle spans ~2.5
    out = tmp_path / "corner.wav"
    fb = f"{2 * 2 * math.pi * 110:.2f}"
    cmd = ["render", "--f0", "110", "--fb", fb, "--vb", "0.28", "-d", "1", "--model", str(m.path), str(out)]
    p = subprocess.run([sys.executable, "-m", "bowsynth", *cmd], capture_output=True, text=True, timeout=300)
    assert p.returncode != 0 and "still silent" in p.stderr and len(p.stderr.strip().splitlines()) == 1, p.stderr
    assert not out.exists()
