"""An attack from F_B = 0 at fast bows: F_B / w 0 -> 0.2 over 50 ms at f0 100, v_B 0.23 / 0.25 / 0.28,
1.5 s, scored per 100 ms frame against a x100 FDM driven by the same curve (metrics.frame_errors), played by the
renderer's pick and by each named model, in auto windows.

    PYTHONPATH=. .venv/bin/python benchmarks/attack_speeds.py [--models soft-range,soft-fast]
"""

from __future__ import annotations

import argparse
import math
import warnings
from pathlib import Path

from bowsynth import BowsynthError, Scene
from bowsynth.metrics import frame_errors
from bowsynth.api import render


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", default="soft-range,soft-fast", help="models to play it besides the pick")
    a = ap.parse_args(argv)
    print("| v_B | played by | model | harmonics median (dB) | pitch median (cents) |\n|---|---|---|---|---|")
    for vb in (0.23, 0.25, 0.28):
        sc = Scene(f0=100.0, fb=[[0.0, 0.0], [0.05, 0.2 * 2 * math.pi * 100.0]], vb=vb, duration=1.5)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            truth = render(sc, engine="fdm", oversample=100)
        for m in [None, *a.models.split(",")]:
            try:
                r = render(sc, engine="operator", model=m, windows="auto")
            except BowsynthError as e:
                print(f"| {vb:g} | {m or 'the pick'} | not played: {str(e).splitlines()[0][:80]} | | |")
                continue
            e = frame_errors(r.p, truth.p, sc.sample_rate)
            print(f"| {vb:g} | {m or 'the pick'} | {Path(r.info.model_path).stem} | {e['harm_db_median']:.3f} | "
                  f"{e['cents_median']:.3f} |")


if __name__ == "__main__":
    main()
