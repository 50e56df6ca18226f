"""Would float16 weights sound the same? (a lead for the one-voice loop at width 128, which streams its
weights from the L2 cache.) Held soft bows rendered 2 s from rest with the shipped `soft-range` as trained (float32)
and with every weight matrix rounded to float16 and back, both against a x100 FDM: harmonics (worst, dB), pitch
(cents) and onset (ms), and how far apart the two waveforms are.

    PYTHONPATH=. .venv/bin/python benchmarks/weights_fp16.py
"""

from __future__ import annotations

import math
import warnings

import numpy as np

from bowsynth import Scene
from bowsynth.metrics import listener_errors
from bowsynth.api import render
from bowsynth.engines.operator.basis import numpy_operator
from bowsynth.engines.operator.choose import SHIPPED_DIR
from bowsynth.engines.operator.modelfile import load_model

BOWS = [(103.6, 0.130, 0.166), (344.4, 0.183, 0.152), (509.8, 0.054, 0.141), (807.4, 0.141, 0.149),
        (170.7, 0.228, 0.191)]  # (f0, F_B / w, v_B): five of benchmarks/listener.py's held soft bows (seed 2026)


def main() -> None:
    path = SHIPPED_DIR / "soft-range.safetensors"
    m32, m16 = load_model(path), load_model(path)
    op = numpy_operator(m16)  # the loops' float32 weights, converted once per model object: round this one's
    op.weights = tuple(np.ascontiguousarray(w.astype(np.float16).astype(np.float32)) if w.ndim >= 2 else w
                       for w in op.weights)
    print("| f0 (Hz) | F_B / w | v_B | float32: harmonics dB / cents / onset ms | float16 weights | max |difference| "
          "/ peak |\n|---|---|---|---|---|---|")
    for f0, beta, vb in BOWS:
        sc = Scene(f0=f0, fb=beta * 2 * math.pi * f0, vb=vb, duration=2.0)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            truth = render(sc, engine="fdm", oversample=100)
        cells, ps = [], []
        for m in (m32, m16):
            p = render(sc, engine="operator", model=m).p
            e = listener_errors(p, truth.p, sc.sample_rate)
            cells.append(f"{e['harm_db_max']:.3f} / {e['cents']:+.3f} / {e['onset_err_ms']:+.1f}")
            ps.append(p)
        d = np.max(np.abs(ps[0] - ps[1])) / np.max(np.abs(ps[0]))
        print(f"| {f0:g} | {beta:g} | {vb:g} | {cells[0]} | {cells[1]} | {d:.2e} |")


if __name__ == "__main__":
    main()
