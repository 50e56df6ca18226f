"""A held note's pitch over its periods from rest, per model and windows: how a lock pulls the note in.
Each column is the pitch over that many of the physics' periods (interpolated zero crossings of q), in cents re the
physics' sounding ratio, against an FDM at x10 in the first row.

    PYTHONPATH=. .venv/bin/python benchmarks/pull_in.py BETA VB MODEL:WINDOWS[,MODEL:WINDOWS...] [--f0 100]
        [--periods 600] [--span 20]
"""

from __future__ import annotations

import argparse
import math
import warnings

from bowsynth import Scene
from bowsynth.metrics import cents, f0_estimate
from bowsynth.api import render
from bowsynth.music.tuning import sounding_ratio


def pitch_by_span(q, sample_rate: float, period: float, periods: int, span: int) -> list[float]:
    """The frequency (Hz) over each run of `span` periods (each `period` samples long) of q."""
    out = []
    for k in range(0, periods, span):
        a, b = int(k * period), int((k + span) * period)
        out.append(f0_estimate(q[a:b], sample_rate, tail=1.0))
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("beta", type=float)
    ap.add_argument("vb", type=float)
    ap.add_argument("plays", help="MODEL:WINDOWS, comma-separated (windows: free, locked, physics, auto)")
    ap.add_argument("--f0", type=float, default=100.0)
    ap.add_argument("--periods", type=int, default=600)
    ap.add_argument("--span", type=int, default=20)
    args = ap.parse_args(argv)
    r = sounding_ratio(args.beta, args.vb, 100.0).r
    hz = args.f0 * r
    sc = Scene(f0=args.f0, fb=args.beta * 2 * math.pi * args.f0, vb=args.vb, duration=args.periods / hz)
    period = sc.sample_rate / hz
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rows = [("FDM x10", render(sc, engine="fdm", oversample=10).q)]
    for spec in args.plays.split(","):
        model, windows = spec.split(":")
        rows.append((spec, render(sc, model=model, windows=windows).q))
    starts = range(0, args.periods, args.span)
    print(f"F_B / w {args.beta:g}, v_B {args.vb:g} at f0 {args.f0:g} Hz (sounding {r:.4f} f0); cents re the "
          f"physics per {args.span} periods from rest")
    print("| | " + " | ".join(f"{k}-{k + args.span}" for k in starts) + " |")
    print("|---|" + "---|" * len(starts))
    for name, q in rows:
        f = pitch_by_span(q, sc.sample_rate, period, args.periods, args.span)
        print(f"| {name} | " + " | ".join(f"{cents(x, hz):+.2f}" for x in f) + " |")


if __name__ == "__main__":
    main()
