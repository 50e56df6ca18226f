"""One model, many pitches: NMSE(p) of a 1 s render from rest against a x100 FDM, for each shipped model at several
pitches with the model's F_B / w (so the model covers the scene).

    .venv/bin/python benchmarks/pitches.py

Where T / dtau is a whole number (f0 100, 150, 300 at 44.1 kHz with a window of 2 pi) every window holds the same
samples; elsewhere windows of two lengths keep their starts on the multiples of T (see docs/BENCHMARKS.md).
"""

import math

from bowsynth import Scene, render_fdm
from bowsynth.metrics import nmse
from bowsynth.engines.operator.choose import SHIPPED_DIR
from bowsynth.engines.operator.engine import render_operator
from bowsynth.engines.operator.modelfile import load_model

PITCHES = (100, 150, 200, 300, 400)


def main():
    print("| model | " + " | ".join(f"f0 {f}" for f in PITCHES) + " |")
    print("|---|" + "---|" * len(PITCHES))
    for path in sorted(SHIPPED_DIR.glob("*.safetensors")):
        m = load_model(path)
        cells = []
        for f0 in PITCHES:
            sc = Scene(**{**m.meta.scene, "f0": f0, "fb": m.domain.beta * 2 * math.pi * f0, "duration": 1.0})
            cells.append(f"{nmse(render_operator(sc, model=m).p, render_fdm(sc, oversample=100).p):.1e}")
        print(f"| {path.stem} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
