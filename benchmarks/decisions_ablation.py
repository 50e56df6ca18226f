"""What each decision a render makes from what ships buys, truth-free: the same random held bows played by the
operator under one config a row (the default; each rule replaced by its simpler alternative), every reference entry
point raising during the operator's render, against one x100 FDM a bow.

    PYTHONPATH=. .venv/bin/python benchmarks/decisions_ablation.py [--n 24] [--seed 7911] [--seconds 2]

Rows: `default` (the model `music.pick` chooses for a held note, whose own cycle lies nearest the shipped map's
period; auto windows: locked to the physics' period where the operator measures that the lock keeps its harmonics,
else free); `free`, `locked`, `physics` (the same model, those windows everywhere); `static pick` (the covering model
`engines.operator.choose.find_model` ranks first, the smallest box, in auto windows: no map in the choice). Printed: a
Markdown table of medians and worst cases over the sounding bows each row played, and how many bows are within 1 dB
(harmonics 2-10, worst) and 1 cent; the truth's own conditioning is not measured here (benchmarks/truth_free.py does).
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import tempfile
import warnings

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))

from truth_free import ReferenceRan, draw, no_reference, truth_of  # noqa: E402

from bowsynth import BowsynthError  # noqa: E402
from bowsynth.api import render  # noqa: E402
from bowsynth.metrics import listener_errors, note_sounds  # noqa: E402

ROWS = {"default": {}, "free": {"windows": "free"}, "locked": {"windows": "locked"},
        "physics": {"windows": "physics"}, "static pick": {"static": True}}


def play(sc, cfg):
    from bowsynth.engines.operator.choose import find_model

    with warnings.catch_warnings(), no_reference():
        warnings.simplefilter("ignore")
        model = find_model(sc) if cfg.get("static") else None
        return render(sc, engine="operator", model=model, windows=cfg.get("windows"))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=24)
    ap.add_argument("--seed", type=int, default=7911)
    ap.add_argument("--seconds", type=float, default=2.0)
    a = ap.parse_args(argv)
    os.environ["BOWSYNTH_CACHE"] = tempfile.mkdtemp(prefix="ablation-cache-")  # cold: nothing measured before
    errs = {k: [] for k in ROWS}
    sounding = 0
    for f0, beta, vb in draw(a.n, a.seed):
        sc, truth = truth_of(f0, beta, vb, a.seconds)
        if not note_sounds(truth.p):
            continue
        sounding += 1
        for name, cfg in ROWS.items():
            try:
                op = play(sc, cfg)
            except (BowsynthError, ReferenceRan) as e:
                errs[name].append(None)
                print(f"{f0:.1f} {beta:.4g} {vb:.4g} {name}: not played ({str(e).splitlines()[0][:100]})",
                      file=sys.stderr)
                continue
            e = listener_errors(op.p, truth.p, sc.sample_rate)
            errs[name].append((e["harm_db_median"], e["harm_db_max"], abs(e["cents"])))
            print(f"{f0:.1f} {beta:.4g} {vb:.4g} {name}: {e['harm_db_max']:.3g} dB worst, {e['cents']:+.3g} cents",
                  file=sys.stderr, flush=True)
    print(f"{sounding} sounding bows of {a.n} (seed {a.seed}, {a.seconds:g} s from rest, x100 FDM truth)\n")
    print("| config | played | harmonics median dB | harmonics worst dB (median / max) | pitch median / max cents "
          "| within 1 dB and 1 cent |")
    print("|---|---|---|---|---|---|")
    for name, rows in errs.items():
        got = [r for r in rows if r is not None and all(math.isfinite(x) for x in r)]
        if not got:
            print(f"| {name} | 0 of {len(rows)} | | | | |")
            continue
        med, worst, cents = (np.array(x) for x in zip(*got))
        ok = int(np.sum((worst <= 1.0) & (cents <= 1.0)))
        print(f"| {name} | {len(got)} of {len(rows)} | {np.median(med):.3f} | {np.median(worst):.3f} / "
              f"{worst.max():.2f} | {np.median(cents):.3f} / {cents.max():.2f} | {ok} |")


if __name__ == "__main__":
    main()
