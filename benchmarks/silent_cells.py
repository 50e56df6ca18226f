"""The cells of `bench map` where the truth is silent (a bow that damps the mass, v_B 0 and 0.04, from rest), played by
the operator of a checkout: p's standard deviation over each 2 s note's second half; then bow stops (v_B 0.2 -> 0 over
0.5-0.6 s, held at 0 to 2.5 s): p's standard deviation over 0.7-1.0 s and from 1.5 s, the operator's and the x8
FDM's. Results: docs/BENCHMARKS.md, "A held bow that damps the mass comes to rest".

    .venv/bin/python benchmarks/silent_cells.py [TREE]     # TREE: another checkout (default: this one)

Another tree is imported ahead of this install (its editable finder dropped, as benchmarks/chorale_trees.py does) on
this checkout's compiled core; its source digest is not checked, so TREE's rest flow must be one this core runs alike
(an underdamped one, where the two agree).
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.meta_path = [f for f in sys.meta_path if type(f).__name__ != "ScikitBuildRedirectingFinder"]
TREE = Path(sys.argv[1] if len(sys.argv) > 1 else Path(__file__).resolve().parent.parent).resolve()
sys.path.insert(0, str(TREE))

import math  # noqa: E402
import warnings  # noqa: E402

import numpy as np  # noqa: E402

import bowsynth  # noqa: E402
import bowsynth.compiled  # noqa: E402

assert Path(bowsynth.__file__).resolve().is_relative_to(TREE), bowsynth.__file__
HERE = Path(__file__).resolve().parent.parent
if TREE != HERE:
    bowsynth.compiled.source_digest = lambda path: None
    import shutil

    for so in (HERE / "bowsynth").glob("_core*.so"):
        if not (TREE / "bowsynth" / so.name).exists():
            shutil.copy(so, TREE / "bowsynth" / so.name)

from bowsynth import Scene  # noqa: E402
from bowsynth.api import render  # noqa: E402

BETAS = (0.02, 0.0334, 0.0557, 0.0928, 0.155, 0.258, 0.431, 0.719, 1.2)  # bench map's columns a model covers


def main() -> None:
    warnings.simplefilter("ignore")
    print(f"tree {TREE}\n\n| f0 | v_B | F_B / w | p std, second half |\n|---|---|---|---|")
    stds = []
    for f0 in (110.0, 440.0):
        for vb in (0.0, 0.04):
            for b in BETAS:
                r = render(Scene(f0=f0, fb=b * 2 * math.pi * f0, vb=vb, duration=2.0), engine="operator")
                stds.append(float(np.std(r.p[len(r.p) // 2:])))
                print(f"| {f0:g} | {vb:g} | {b:g} | {stds[-1]:.2e} |")
    s = np.array(stds)
    print(f"\n{len(s)} cells; above 1e-4 (bench map's 'sounds'): {int((s > 1e-4).sum())}; std median "
          f"{np.median(s):.2g}, worst {s.max():.2g}")
    print("\n| bow stop: f0 | F_B / w | operator 0.7-1.0 s | FDM x8 | operator from 1.5 s | FDM x8 |")
    print("|---|---|---|---|---|---|")
    for f0, b in ((110.0, 0.1), (110.0, 0.3), (220.0, 0.2), (440.0, 0.05), (110.0, 1.0)):
        sc = Scene(f0=f0, fb=b * 2 * math.pi * f0, vb=[(0.0, 0.2), (0.5, 0.2), (0.6, 0.0)], duration=2.5)
        op, ref = render(sc, engine="operator"), render(sc, engine="fdm", oversample=8)
        mid, end = slice(int(0.7 * 44100), 44100), slice(int(1.5 * 44100), None)
        print(f"| {f0:g} | {b:g} | {np.std(op.p[mid]):.2e} | {np.std(ref.p[mid]):.2e} | {np.std(op.p[end]):.2e} | "
              f"{np.std(ref.p[end]):.2e} |")


if __name__ == "__main__":
    main()
