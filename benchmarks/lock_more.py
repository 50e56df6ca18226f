"""A held note locked to the physics' period in the fewest windows that fill it and in 1..3 more a period: its
pitch and harmonics against the x100 FDM (2 s from rest, scored over the last second, as benchmarks/listener.py), and
in free windows. Where a lock's windows end in the cycle sets its harmonics.

    PYTHONPATH=. .venv/bin/python benchmarks/lock_more.py F0 BETA VB MODEL
"""

from __future__ import annotations

import math
import sys
import warnings

from bowsynth import Scene
from bowsynth.metrics import listener_errors
from bowsynth.api import render
from bowsynth.engines import render as engine_render
from bowsynth.engines.operator.windows import Lock
from bowsynth.music.tuning import sounding_ratio


def main() -> None:
    if len(sys.argv) != 5:
        sys.exit(__doc__)
    f0, beta, vb, model = float(sys.argv[1]), float(sys.argv[2]), float(sys.argv[3]), sys.argv[4]
    r = sounding_ratio(beta, vb, 100.0).r
    sc = Scene(f0=f0, fb=beta * 2 * math.pi * f0, vb=vb, duration=2.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        truth = render(sc, engine="fdm", oversample=100)
    print(f"{model} at F_B / w {beta:g}, v_B {vb:g}, {f0:g} Hz, against the x100 FDM")
    print("| windows | cents | harmonics median / worst (dB) |")
    print("|---|---|---|")
    for more in (None, 0, 1, 2, 3):
        op = engine_render(sc, engine="operator", model=model, sounding=None if more is None else Lock(f0 * r, more))
        e = listener_errors(op.p, truth.p, sc.sample_rate)
        how = "free" if more is None else f"locked, the fewest + {more}"
        print(f"| {how} | {e['cents']:+.3f} | {e['harm_db_median']:.3f} / {e['harm_db_max']:.3f} |")


if __name__ == "__main__":
    main()
