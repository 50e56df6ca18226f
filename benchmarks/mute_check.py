"""Does the truth speak by the time `onset.mute_from` says a note must have spoken?

    PYTHONPATH=. .venv/bin/python benchmarks/mute_check.py [--oversample 8] [--seconds 2]

The measurement behind engines/operator/onset.py's MUTE_FRACTION and MUTE_SAFETY: over `bench map`'s grid of bows
(F_B / w 0.02-2 x v_B 0-0.28) at 110 and 440 Hz, each note 2 s from rest by the FDM, for every bow above vb_stop:
t_speak (the linearised growth from the note's offset to the scale v_B - vb_stop), when the truth's p first spans a
quarter of the scale over four free periods, and how much its last four span against the scale (a stick-slip
cycle at F_B / w 2 is three free periods). Printed: the bows where the truth was later than t_speak, the least span of
the last four periods among the bows the check judges (1.5 t_speak inside the note), and any truth it calls mute.
"""

from __future__ import annotations

import argparse
import math

import numpy as np

from bowsynth import Scene, physics, render_fdm
from bowsynth.analysis.error_map import grid
from bowsynth.engines.operator.onset import MUTE_FRACTION, MUTE_SAFETY, mute_from, speak_time


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--oversample", type=int, default=8)
    ap.add_argument("--seconds", type=float, default=2.0)
    args = ap.parse_args(argv)
    betas, vbs = grid(10, 8)
    late, judged, flagged = [], [], []
    for f0 in (110.0, 440.0):
        for vb in vbs:
            for b in betas:
                sc = Scene(f0=f0, fb=b * 2 * math.pi * f0, vb=vb, duration=args.seconds)
                tau = speak_time(sc)
                if tau is None:  # the bow does not drive the mass
                    continue
                t_speak, scale = tau / sc.omega, vb - physics.vb_stop(sc.a)
                p = render_fdm(sc, oversample=args.oversample).p
                period = int(4 * sc.sample_rate / f0) + 1
                step = period // 4
                hit = next((k / sc.sample_rate for k in range(0, len(p) - period, step)
                            if np.ptp(p[k:k + period]) > MUTE_FRACTION * scale), None)
                if hit is not None and hit > t_speak:
                    late.append((f0, b, vb, t_speak, hit))
                if MUTE_SAFETY * t_speak < args.seconds:
                    judged.append((np.ptp(p[-period:]) / scale, f0, b, vb))
                if mute_from(sc, p) is not None:
                    flagged.append((f0, b, vb))
    print(f"bows above vb_stop judged by the check: {len(judged)}; the truth later than t_speak: {len(late)} {late}")
    span, f0, b, vb = min(judged)
    print(f"least span of the last four periods / (v_B - vb_stop) among them: {span:.2f} (f0 {f0:g}, "
          f"F_B / w {b:.3g}, v_B {vb:g}); the check's threshold {MUTE_FRACTION}")
    print(f"truths the check would call mute: {len(flagged)} {flagged}")


if __name__ == "__main__":
    main()
