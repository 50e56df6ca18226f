"""The stick capture at F_B 1000 (the paper's stick-slip scene, f0 100, v_B 0.2, a 100): max |p - p_ref|
over the limit cycle as a share of the x100 FDM's p range, per model and windows, early (1-3 s) and late (the last
3-1 s) in a long note from rest. Two readings: sample by sample (which also reads the cycle's phase: a note
that speaks 2 ms early has its slip edges 2 ms ahead, up to the whole range) and the cycle's shape
(`metrics.cycle_shape_error`: one shift for the whole span, so a drifting pitch still shows), read twice: with a
whole-sample shift, and with a shift on the x100 FDM's own steps (a cycle's phase between samples: the truth half a
sample late reads 1.19 % against itself with whole samples, at the capture's knee). Also the p range's error, the
pitch (cents) and harmonics 1-10 against the truth (`metrics.listener_errors`, the last second). The truth is kept at
every step of its scheme: 2 GB for 30 s.

    PYTHONPATH=. .venv/bin/python benchmarks/stick_capture.py [--seconds 30] [MODEL:WINDOWS ...]

MODEL `pick` is the model a render of the scene picks (`choose.find_model`).

Results: docs/BENCHMARKS.md, "The stick capture at F_B 1000".
"""

from __future__ import annotations

import argparse
import time
import warnings
from pathlib import Path

import numpy as np

from bowsynth.metrics import cycle_shape_error, listener_errors
from bowsynth.engines.fdm import TRUTH_OVERSAMPLE, fdm_steps_p
from bowsynth.engines.operator.choose import as_model, find_model
from bowsynth.engines.operator.engine import render_operator
from bowsynth.music.engine_tuning import sounding_for
from bowsynth.scene import Scene

DEFAULT = ["pick:auto", "paper-fb1000-half:auto", "paper-fb1000-knee:auto", "paper-fb1000:free", "paper-fb1000:physics",
           "stick-mid:free", "stick-mid:physics", "stick-high:physics"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", nargs="*", default=DEFAULT, help="MODEL:WINDOWS (free, locked, physics or auto)")
    ap.add_argument("--seconds", type=float, default=30.0)
    args = ap.parse_args()
    sc = Scene(f0=100.0, fb=1000.0, vb=0.2, duration=args.seconds)
    sr = sc.sample_rate
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fine = fdm_steps_p(sc, TRUTH_OVERSAMPLE)
    os_ = TRUTH_OVERSAMPLE
    ref_p = fine[::os_]
    print(f"F_B 1000, v_B 0.2, f0 100, {args.seconds:g} s from rest; truth: FDM x{TRUTH_OVERSAMPLE} "
          f"({time.perf_counter() - t0:.1f} s)\n")
    spans = [(1.0, 3.0), (args.seconds - 3.0, args.seconds - 1.0)]
    head = " | ".join(f"{a:g}-{b:g} s: sample / shape, whole samples / shape (shift ms) / range" for a, b in spans)
    print(f"| model | windows | {head} | cents | harmonics median / worst (dB) |")
    print("|---|---|" + "---|" * len(spans) + "---|---|")
    shift = int(round(sr / 100.0 / 0.7))  # about a sounding period (the note sounds at ~0.73 f0)
    for run in args.runs:
        name, _, windows = run.partition(":")
        m = find_model(sc) if name == "pick" else as_model(name)
        name = f"{Path(m.path).stem} (the pick)" if name == "pick" else name
        r = render_operator(sc, model=m, sounding=sounding_for(sc, windows or "free", m))
        cells = []
        for a, b in spans:
            i, j = int(a * sr), int(b * sr)
            p, pr = r.p[i:j].astype(float), ref_p[i:j]
            rng = float(pr.max() - pr.min())
            whole, _ = cycle_shape_error(p, pr, shift)
            shape, s = cycle_shape_error(p, fine[i * os_:(j - 1) * os_ + 1], shift, oversample=os_)
            cells.append(f"{100 * np.max(np.abs(p - pr)) / rng:.2f} % / {100 * whole:.2f} % / "
                         f"**{100 * shape:.2f} %** ({1000 * s / sr:+.3f}) / {100 * (np.ptp(p) - rng) / rng:+.2f} %")
        e = listener_errors(r.p, ref_p, sr)
        print(f"| {name} | {windows or 'free'} | {' | '.join(cells)} | {e['cents']:+.3f} | "
              f"{e['harm_db_median']:.3f} / {e['harm_db_max']:.3f} |")


if __name__ == "__main__":
    main()
