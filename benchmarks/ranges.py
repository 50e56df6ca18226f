"""Range models against the truth: held-out bows, gestures, the stick-capture shape, speed.

    PYTHONPATH=. .venv/bin/python benchmarks/ranges.py [MODEL.safetensors ...] [--quick] [--json out.json]

Default: the shipped range models (models/*range*.safetensors). For each model:

1. Held-out bows: the 4 x 4 grid of cell centres of its box (log beta; the training bows are a Latin hypercube drawn
   with another seed, so no grid point is a training point) at several pitches, 1 s from rest, operator against the
   x100 FDM: NMSE(p) and the pitch error (cents, interpolated zero crossings over the second half). Bows where the
   note does not speak within 1 s (ranges.speaks) are reported apart: they must stay quiet and finite.
2. Gestures inside the box, 1 s at f0 100: the operator against the x100 FDM driven by the controls the operator
   applied (held per window, at the window's middle), and against the x100 FDM of the continuous curves (the cost
   of the control rate).
3. Stick-slip models: the stick-capture shape at F_B 1000 (f0 100, v_B 0.2, 3 s, after 1 s): max |p - p_ref| over
   the p range, and the peaks.
4. Rollout speed, one voice, 5 s at f0 100 (compiled loop, in process).
"""

from __future__ import annotations

import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from bowsynth import Scene, render_fdm
from bowsynth.metrics import nmse
from bowsynth.analysis.out_of_sample import bench_parameter_points, parameter_summary
from bowsynth.controls import Curve
from bowsynth.engines.operator.choose import SHIPPED_DIR
from bowsynth.engines.operator.engine import render_operator
from bowsynth.engines.operator.modelfile import load_model
from bowsynth.engines.operator.rollout import rollout_states, scene_bows

PITCHES = (65.0, 100.0, 220.0, 440.0)
REF = 100


def held_out(m, pitches, n=4):
    return bench_parameter_points(m, pitches, n)


def step_curve(bows_per_window, starts, ends, sample_rate, scale=1.0):
    """The operator's applied control as a curve for the FDM: each window's value held over it (a 1 ns ramp at
    each window edge, far below the x100 FDM's step)."""
    pts = []
    for v, s, e in zip(bows_per_window, starts, ends):
        pts += [(s / sample_rate, v * scale), (e / sample_rate - 1e-9, v * scale)]
    return Curve(tuple(pts))


def gesture(m, name, fb, vb, f0=100.0, seconds=1.0):
    from bowsynth.engines.operator.basis import numpy_operator
    from bowsynth.engines.operator.windows import window_bounds

    sc = Scene(f0=f0, fb=fb, vb=vb, a=m.domain.a, duration=seconds)
    r = render_operator(sc, model=m, fallback="fdm")
    spw = numpy_operator(m).samples_per_window(sc.dtau)
    bows = scene_bows(sc, spw)
    st, en = window_bounds(spw, sc.n_samples)
    applied = sc.replace(fb=step_curve(bows[:, 0], st, en, sc.sample_rate, sc.omega),
                         vb=step_curve(bows[:, 1], st, en, sc.sample_rate))
    ref_applied = render_fdm(applied, oversample=REF)
    ref_curve = render_fdm(sc, oversample=REF)
    return {"gesture": name, "method": r.method, "nmse_vs_applied": float(nmse(r.p, ref_applied.p)),
            "nmse_vs_curves": float(nmse(r.p, ref_curve.p)),
            "control_rate_cost": float(nmse(ref_applied.p, ref_curve.p)),
            "finite": bool(np.isfinite(r.p).all())}


def gestures_for(m, f0=100.0):
    b0, b1, v0, v1 = m.domain.box
    w = 2 * math.pi * f0
    out = []
    if b1 <= 0.5:  # soft range
        lo, hi = max(b0, 0.05), min(b1, 0.35)
        out.append(("crescendo beta %.3g->%.3g in 1 s, v_B 0.2" % (lo, hi), [[0, lo * w], [1, hi * w]], 0.2))
        out.append(("bow speed 0.1->0.28 in 1 s, beta 0.2", 0.2 * w, [[0, 0.1], [1, 0.28]]))
        out.append(("bow stop v_B 0.2->0.05 in 0.1 s at 0.5 s, beta 0.2", 0.2 * w,
                    [[0.5, 0.2], [0.6, max(0.05, v0)]]))
    else:
        out.append(("stick-slip swell beta 1.1->1.9 in 1 s, v_B 0.2", [[0, 1.1 * w], [1, 1.9 * w]], 0.2))
        out.append(("bow speed 0.12->0.28 in 1 s, beta 1.5", 1.5 * w, [[0, 0.12], [1, 0.28]]))
    return [gesture(m, name, fb, vb, f0) for name, fb, vb in out]


def stick_capture(m):
    # a point model (no box) is its own box of zero width: paper-fb1000 is a model that plays F_B 1000
    b0, b1, v0, v1 = m.domain.box or (m.domain.beta, m.domain.beta, m.domain.vb, m.domain.vb)
    beta = 1000 / (2 * math.pi * 100)
    if not (b0 * (1 - 1e-9) <= beta <= b1 * (1 + 1e-9) and v0 <= 0.2 <= v1):
        return None
    sc = Scene(f0=100.0, fb=1000.0, vb=0.2, a=m.domain.a, duration=3.0)
    r = render_operator(sc, model=m, fallback="fdm")
    ref = render_fdm(sc, oversample=REF)
    i = sc.sample_rate  # after 1 s
    p, pr = r.p[i:].astype(float), ref.p[i:]
    rng = float(pr.max() - pr.min())
    return {"max_abs_err_over_range_percent": 100 * float(np.max(np.abs(p - pr))) / rng,
            "p_max": float(p.max()), "p_max_ref": float(pr.max()), "p_min": float(p.min()),
            "p_min_ref": float(pr.min()),
            "p_range_error_percent": 100 * ((p.max() - p.min()) - rng) / rng, "method": r.method,
            "nmse_1_3s": float(nmse(p, pr))}


def speed(m, seconds=5.0, repeats=5):
    sc = Scene(f0=100.0, fb=m.domain.beta * 2 * math.pi * 100, vb=m.domain.vb, a=m.domain.a, duration=seconds)
    rollout_states(m, [[0.0, 0.0]], 100, sc.dtau, loop="core")  # load the model's bases
    best = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        rollout_states(m, [[0.0, 0.0]], sc.n_samples, sc.dtau, loop="core", params=[m.domain.beta, m.domain.vb])
        best = min(best, time.perf_counter() - t0)
    return {"seconds_audio": seconds, "rollout_s": best, "realtime_x": seconds / best}


def main(argv):
    quick = "--quick" in argv
    out_json = None
    if "--json" in argv:
        out_json = argv[argv.index("--json") + 1]
    paths = [a for a in argv if a.endswith(".safetensors")] or sorted(str(p) for p in SHIPPED_DIR.glob("*range*.safetensors"))
    result = {}
    for path in paths:
        m = load_model(path)
        print(f"\n## {path}  ({m.id}, {m.domain.describe_bows()}, a {m.domain.a:g}; trained "
              f"{m.meta.training.get('seconds')} s, {m.meta.training.get('steps_done')} steps)")
        rows = held_out(m, PITCHES[:2] if quick else PITCHES)
        s = parameter_summary(rows)
        print(f"held-out 4 x 4 grid x {len(PITCHES[:2] if quick else PITCHES)} pitches, 1 s from rest vs FDM x{REF}: "
              f"{s}")
        print("| f0 | F_B / w | v_B | speaks | NMSE(p) | cents | max abs p (op / ref) | engine |")
        print("|---|---|---|---|---|---|---|---|")
        for r in rows:
            print(f"| {r['f0']:g} | {r['beta']:.4g} | {r['vb']:.4g} | {'yes' if r['speaks'] else 'no'} | "
                  f"{r.get('nmse', float('nan')):.2e} | {r.get('cents', float('nan')):+.3f} | "
                  f"{r['max_abs_p']:.3g} / {r['ref_max_abs_p']:.3g} | {r['method']} |")
        g = gestures_for(m)
        print("| gesture | NMSE(p) vs FDM of applied controls | vs FDM of the curves | control-rate cost | engine |")
        print("|---|---|---|---|---|")
        for r in g:
            print(f"| {r['gesture']} | {r['nmse_vs_applied']:.2e} | {r['nmse_vs_curves']:.2e} | "
                  f"{r['control_rate_cost']:.2e} | {r['method']} |")
        sc = stick_capture(m)
        if sc:
            print(f"stick capture at F_B 1000: {sc}")
        sp = speed(m)
        print(f"speed: {sp}")
        result[path] = {"id": m.id, "summary": s, "rows": rows, "gestures": g, "stick_capture": sc, "speed": sp,
                        "training": {k: m.meta.training.get(k) for k in ("seconds", "steps_done")}}
    if out_json:
        Path(out_json).write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    main(sys.argv[1:])
