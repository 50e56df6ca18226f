"""Does a model settle on the instrument's limit cycle from anywhere in its domain, and stay on pitch for 30 s?

    PYTHONPATH=. .venv/bin/python benchmarks/stability.py MODEL [MODEL ...] [--seeds 1,2,3] [--voices 64]

The measurement behind `tests/test_stability.py`'s limit-cycle test, for any model file (a candidate before it ships):
voices started at random states of the model's domain at its own centre bow (the scene in its metadata), 2 s each,
the domain check on. Printed per seed: how many voices left the domain, the largest relative amplitude deviation of
the others from the FDM's limit cycle (x8, last 0.5 s) and their largest pitch error; then the pitch of the last 5 s
of a 30 s render against the FDM's steady state. A wrong limit cycle (a loud wrong note) shows as an amplitude
deviation of order 1.
"""

from __future__ import annotations

import argparse

import numpy as np

from bowsynth import Scene, render_fdm
from bowsynth.metrics import cents, f0_estimate
from bowsynth.engines.operator.engine import render_operator
from bowsynth.engines.operator.modelfile import load_model
from bowsynth.engines.operator.onset import settled_seconds
from bowsynth.engines.operator.rollout import rollout_states


def convergence(m, seed: int, voices: int):
    d = m.domain
    rng = np.random.default_rng(seed)
    x = rng.uniform([d.q_lo, d.p_lo], [d.q_hi, d.p_hi], size=(100 * voices, 2))
    x = x[d.contains(x[:, 0], x[:, 1])][:voices]
    sc = Scene(**m.meta.scene)
    q, p, fail = rollout_states(m, x, 2 * sc.sample_rate, sc.omega / sc.sample_rate)
    ok = fail[:, 0] == -1
    # the FDM's limit cycle: its last 0.5 s once the note has spoken (a light fast bow takes seconds)
    ref = render_fdm(sc.replace(duration=settled_seconds(sc)), oversample=8)
    tail = slice(-sc.sample_rate // 2, None)
    amp = np.abs(p[ok][:, tail]).max(1) / np.abs(ref.p[tail]).max() - 1
    f_ref = f0_estimate(ref.q[tail], sc.sample_rate, tail=1.0)
    off = [abs(cents(f0_estimate(v[tail], sc.sample_rate, tail=1.0), f_ref)) for v in q[ok]]
    return len(x), int((~ok).sum()), amp, max(off)


def long_pitch(m) -> float:
    sc = Scene(**{**m.meta.scene, "duration": 30.0})
    r = render_operator(sc, model=m)
    ref = render_fdm(sc.replace(duration=settled_seconds(sc, after=5.0)), oversample=8)
    return cents(f0_estimate(r.q[-5 * sc.sample_rate:], sc.sample_rate, tail=1.0),
                 f0_estimate(ref.q, sc.sample_rate))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("models", nargs="+")
    ap.add_argument("--seeds", default="1,2,3", help="the first is the test's")
    ap.add_argument("--voices", type=int, default=64)
    a = ap.parse_args(argv)
    for path in a.models:
        m = load_model(path)
        sc = m.meta.scene
        print(f"{path}: centre bow F_B / w {sc['fb'] / (2 * np.pi * sc['f0']):.3f}, v_B {sc['vb']:.3f}")
        for seed in map(int, a.seeds.split(",")):
            n, left, amp, worst_cents = convergence(m, seed, a.voices)
            print(f"  seed {seed}: {left}/{n} left the domain; amplitude deviation worst {np.abs(amp).max():.2e} "
                  f"(voices over 1 %: {int((np.abs(amp) > 0.01).sum())}); pitch worst {worst_cents:.3f} cents")
        print(f"  30 s render: last 5 s {long_pitch(m):+.3f} cents from the FDM's steady state")


if __name__ == "__main__":
    main()
