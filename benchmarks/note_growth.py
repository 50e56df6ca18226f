"""How long a note from rest takes to reach its limit cycle: the p RMS of a x4 FDM render from rest at f0 100, every
2 s (a half-second frame), at bows of a light fast corner (or those given), and the harmonics 2-5 at its end.

    PYTHONPATH=. .venv/bin/python benchmarks/note_growth.py [--betas 0.012,0.02,0.035,0.06] [--vbs 0.24,0.28,0.3]
                                                            [--seconds 24]
    PYTHONPATH=. .venv/bin/python benchmarks/note_growth.py --model soft-corner --betas 0.02 --vbs 0.28 --seconds 8

With --model: at each bow, the x100 FDM and that model (free windows) from rest, every 0.5 s: p RMS and harmonics 2-5.

In tau the dynamics depend on the bow alone, so t seconds at f0 100 are t / 4.4 s at 440 Hz.
"""

from __future__ import annotations

import argparse

import numpy as np

from bowsynth.metrics import f0_estimate, harmonic_levels
from bowsynth.engines import render
from bowsynth.scene import Scene


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--betas", default="0.012,0.02,0.035,0.06")
    ap.add_argument("--vbs", default="0.24,0.28,0.3")
    ap.add_argument("--seconds", type=int, default=24)
    ap.add_argument("--model", default=None, help="compare this model with the x100 FDM over time instead")
    args = ap.parse_args()
    secs = args.seconds
    if args.model:
        return compare(args)
    print(f"| F_B / w | v_B | p RMS at " + " / ".join(f"{t} s" for t in range(0, secs, 2)) + " | harmonics 2-5 at the end (dB) |")
    print("|---|---|---|---|")
    for beta in (float(b) for b in args.betas.split(",")):
        for vb in (float(v) for v in args.vbs.split(",")):
            sc = Scene(f0=100, fb=beta * 2 * np.pi * 100, vb=vb, duration=secs)
            r = render(sc, engine="fdm", oversample=4)
            sr = sc.sample_rate
            rms = [np.sqrt(np.mean(r.p[int(t * sr):int((t + 0.5) * sr)] ** 2)) for t in range(0, secs, 2)]
            tail = r.p[-int(0.5 * sr):]
            lv = harmonic_levels(tail, sr, f0=f0_estimate(tail, sr, tail=1.0))
            print(f"| {beta:g} | {vb:g} | " + " ".join(f"{v:.1e}" for v in rms) + " | "
                  + " ".join(f"{v:.1f}" for v in lv[1:5]) + " |")


def compare(args) -> None:
    from bowsynth.engines.fdm import TRUTH_OVERSAMPLE

    print("| F_B / w | v_B | t (s) | engine | p RMS | harmonics 2-5 (dB) |\n|---|---|---|---|---|---|")
    for beta in (float(b) for b in args.betas.split(",")):
        for vb in (float(v) for v in args.vbs.split(",")):
            sc = Scene(f0=100, fb=beta * 2 * np.pi * 100, vb=vb, duration=args.seconds)
            runs = {"x100 FDM": render(sc, engine="fdm", oversample=TRUTH_OVERSAMPLE),
                    args.model: render(sc, engine="operator", model=args.model)}
            sr = sc.sample_rate
            for t in np.arange(0.0, args.seconds, 0.5):
                for name, r in runs.items():
                    x = r.p[int(t * sr):int((t + 0.5) * sr)]
                    lv = harmonic_levels(x, sr, f0=f0_estimate(x, sr, tail=1.0))
                    print(f"| {beta:g} | {vb:g} | {t:.1f} | {name} | {np.sqrt(np.mean(x ** 2)):.3e} | "
                          + " ".join(f"{v:.1f}" for v in lv[1:5]) + " |")


if __name__ == "__main__":
    main()
