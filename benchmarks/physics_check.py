"""The render-time physics check (operator.check.check_physics): what the shipped models score, what a lying file scores,
and what the check costs.

    OPENBLAS_NUM_THREADS=1 PYTHONPATH=. .venv/bin/python benchmarks/physics_check.py

Rows: each shipped model from rest (its training scene's initial state: what renders check, on the check's own tau
grid), from random states on its trained band (why the check does not start from the render's own state: in an F_B
1000 stick phase two windows of twice the force look alike), the same error on a render's own sample grid at several
pitches (the first two windows of a real render against RK4 at those samples), and the model with its metadata
edited to claim other physics.
"""

import math
import time

import numpy as np

from bowsynth import Scene
from bowsynth.engines.operator import check as R
from bowsynth.engines.operator.modelfile import load_model

PITCHES = (50, 100, 200, 400, 800)


def on_grid(m, sc):
    """The check's error on the scene's own samples: the first two windows of its render against RK4 there."""
    dtau = sc.omega / sc.sample_rate
    n = int(R.CHECK_WINDOWS * R.numpy_operator(m).window / dtau)
    q, p, _ = R.rollout_states(m, [[sc.q0, sc.p0]], n, dtau, check_domain=False, loop="numpy")
    d = m.domain
    rq, rp = R.reference_tau(sc.q0, sc.p0, d.beta, d.vb, d.a, dtau, n)
    lq, lp = R.physics.linear_flow(sc.q0, sc.p0, np.arange(n) * dtau)
    return np.mean((q[0] - rq) ** 2 + (p[0] - rp) ** 2) / np.mean((rq - lq) ** 2 + (rp - lp) ** 2)


def lie(m, **claims):
    """A copy of the model whose metadata claims other physics (as an edited file would, digest fixed up)."""
    m2 = load_model(m.path)
    for k, v in claims.items():
        setattr(m2.meta.domain, k, v)
    return m2


def main():
    worst = 0.0
    print("| model | from rest (tau grid) | 100 states on its band: median, max (not checked) | on the render's grid, f0 " +
          " / ".join(map(str, PITCHES)) + " | check ms (first, cached) |")
    print("|---|---|---|---|---|")
    for path in sorted(R.SHIPPED_DIR.glob("*.safetensors")):
        m = load_model(path)
        t0 = time.perf_counter()
        rest = R.check_physics(m)  # from the training scene's initial state: rest for the shipped models
        first = time.perf_counter() - t0
        t0 = time.perf_counter()
        R.check_physics(m)
        cached = time.perf_counter() - t0
        d = m.domain
        rng = np.random.default_rng(0)
        x = rng.uniform([d.q_lo, d.p_lo], [d.q_hi, d.p_hi], size=(50000, 2))
        x = x[d.contains(x[:, 0], x[:, 1])][:100]
        band = np.percentile([R.physics_error(m, float(a), float(b)) for a, b in x], [50, 100])
        grid = [on_grid(m, Scene(**{**m.meta.scene, "f0": f, "fb": d.beta * 2 * math.pi * f, "duration": 0.1}))
                for f in PITCHES]
        worst = max(worst, rest, *grid)
        print(f"| {path.stem} | {rest:.1e} | {band[0]:.1e}, {band[1]:.1e} | {' / '.join(f'{g:.1e}' for g in grid)} | "
              f"{first * 1e3:.1f}, {cached * 1e3:.3f} |")
    print(f"\nworst legitimate error {worst:.1e}; limit check.PHYSICS_MAX_ERROR = {R.PHYSICS_MAX_ERROR:g} "
          f"({R.PHYSICS_MAX_ERROR / worst:.0f}x above)\n")
    print("| model | metadata claims | error from rest |")
    print("|---|---|---|")
    for path in sorted(R.SHIPPED_DIR.glob("*.safetensors")):
        m = load_model(path)
        d = m.domain
        for label, claims in (("F_B x2", {"beta": 2 * d.beta}), ("F_B x1.5", {"beta": 1.5 * d.beta}),
                              ("F_B x0.5", {"beta": 0.5 * d.beta}), ("F_B x1.1", {"beta": 1.1 * d.beta}),
                              ("v_B 0.25", {"vb": 0.25}), ("a 150", {"a": 150.0})):
            print(f"| {path.stem} | {label} | {R.physics_error(lie(m, **claims), 0.0, 0.0):.2g} |")


if __name__ == "__main__":
    main()
