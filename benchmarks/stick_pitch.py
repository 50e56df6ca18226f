"""The stick-slip point models at any pitch: on whole windows (engines/operator/grid.py) against the output grid's
windows (what renders did before), each against a x100 FDM at the same f0 and bow, the audio-rate FDM beside.

    PYTHONPATH=. .venv/bin/python benchmarks/stick_pitch.py [--models paper-fb1000,scratch-g2]
                                                            [--f0 65,100,220,330,440,523.25,660,880] [--seconds 2]
                                                            [--all-whole]

Each model at its own F_B / w and v_B (F_B scaled with the pitch), from rest. Per note: harmonics 2-10 of p above -50
dB (median / worst dB error over the last second), pitch (cents), onset (ms), NMSE(p), and the operator's render
time (ms, in-process, warm: resampling included).
"""

from __future__ import annotations

import argparse
import math
import warnings

from bowsynth import BowsynthError, Scene, load_model
from bowsynth.metrics import listener_errors, nmse
from bowsynth.api import model_path, render_fdm, render_operator
from bowsynth.engines.operator import engine


def cell(r, truth, sr):
    e = listener_errors(r.p, truth.p, sr)
    return (f"{e['harm_db_median']:.3f} / {e['harm_db_max']:.3f} | {e['cents']:+.3f} | {e['onset_err_ms']:+.1f} | "
            f"{nmse(r.p, truth.p):.2e}")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--models", default="paper-fb1000,scratch-g2")
    ap.add_argument("--f0", default="65,100,220,330,440,523.25,660,880")
    ap.add_argument("--seconds", type=float, default=2.0)
    ap.add_argument("--all-whole", action="store_true",
                    help="whole windows for any model (soft ones too), to compare where the engine does not use them")
    a = ap.parse_args()
    whole = engine.needs_whole_windows
    print("| model | f0 (Hz) | grid | harmonics median / worst (dB) | pitch (cents) | onset (ms) | NMSE(p) | ms |")
    print("|---|---|---|---|---|---|---|---|")
    for name in a.models.split(","):
        m = load_model(model_path(name))
        d = m.domain
        for f0 in (float(x) for x in a.f0.split(",")):
            sc = Scene(f0=f0, fb=d.beta * 2 * math.pi * f0, vb=d.vb, a=d.a, duration=a.seconds)
            truth = render_fdm(sc, oversample=100)
            on = (lambda dom: True) if a.all_whole else whole
            for label, rule in (("output windows (before)", lambda dom: False), ("whole windows", on)):
                engine.needs_whole_windows = rule
                try:
                    render_operator(sc, model=m)  # warm: the bases of this pitch
                    r = render_operator(sc, model=m)
                    row = f"{cell(r, truth, sc.sample_rate)} | {1e3 * r.seconds:.1f}"
                except BowsynthError as e:
                    row = f"refused: {str(e).split(';')[0]} | | | | "
                finally:
                    engine.needs_whole_windows = whole
                print(f"| {name} | {f0:g} | {label} | {row} |", flush=True)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # the FDM raises its own oversampling where it must: said in the row
                fdm = render_fdm(sc)
            print(f"| {name} | {f0:g} | audio-rate FDM (x{fdm.method.oversample}) | "
                  f"{cell(fdm, truth, sc.sample_rate)} | |", flush=True)


if __name__ == "__main__":
    main()
