"""How well conditioned a listener's metrics are at a bow: the x100 FDM from rest at (F_B / w, v_B) against the x100
FDM at a bow 0.1 % (and 1 %) off, each parameter alone and both signs, 2 s at each f0, scored as `bench map` scores
the operator (metrics.listener_errors: harmonics median / worst in dB, pitch cents, onset ms).

    PYTHONPATH=. .venv/bin/python benchmarks/cell_conditioning.py BETA VB [F0,F0...] [--rel 0.001,0.01]

The reference's own study (docs/measures.md) found harmonics move at most 0.06 dB for a bow 0.1 % off; where a note from rest is
still growing at the end of its 2 s (a light, fast bow) they move far more, and an operator's error there is to be
read against this spread, as NMSE from rest was.
"""

from __future__ import annotations

import argparse

import numpy as np

from bowsynth.metrics import listener_errors
from bowsynth.engines import render
from bowsynth.engines.fdm import TRUTH_OVERSAMPLE
from bowsynth.scene import Scene


def truth(f0: float, beta: float, vb: float, seconds: float):
    sc = Scene(f0=f0, fb=beta * 2 * np.pi * f0, vb=vb, duration=seconds)
    return render(sc, engine="fdm", oversample=TRUTH_OVERSAMPLE)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("beta", type=float)
    ap.add_argument("vb", type=float)
    ap.add_argument("f0s", nargs="?", default="110,440")
    ap.add_argument("--rel", default="0.001,0.01")
    ap.add_argument("--seconds", type=float, default=2.0)
    args = ap.parse_args()
    print(f"F_B / w {args.beta:g}, v_B {args.vb:g}: the x100 FDM at a bow off by the share given, against it at the "
          f"bow ({args.seconds:g} s from rest)\n")
    print("| f0 | bow off | harmonics median / worst (dB) | pitch (cents) | onset (ms) |\n|---|---|---|---|---|")
    for f0 in (float(f) for f in args.f0s.split(",")):
        ref = truth(f0, args.beta, args.vb, args.seconds)
        for rel in (float(r) for r in args.rel.split(",")):
            for sign in (1, -1):
                for name in ("F_B / w", "v_B"):
                    b = args.beta * (1 + sign * rel) if name == "F_B / w" else args.beta
                    v = args.vb * (1 + sign * rel) if name == "v_B" else args.vb
                    e = listener_errors(truth(f0, b, v, args.seconds).p, ref.p, ref.scene.sample_rate)
                    print(f"| {f0:g} | {name} {sign * rel:+.1%} | {e['harm_db_median']:.3f} / {e['harm_db_max']:.3f} | "
                          f"{e['cents']:+.3f} | {e['onset_err_ms']:+.2f} |")


if __name__ == "__main__":
    main()
