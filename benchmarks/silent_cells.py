"""The cells of `bench map` where the truth is silent (a bow that damps the mass, v_B 0 and 0.04, from rest), played by
the operator of a checkout: p's standard deviation over each 2 s note's second half. Results: docs/BENCHMARKS.md, "A
held bow that damps the mass comes to rest".

    .venv/bin/python benchmarks/silent_cells.py [TREE]     # TREE: another checkout (default: this one)

Another tree is imported ahead of this install (its editable finder dropped, as benchmarks/chorale_trees.py does) on
this checkout's compiled core; its source digest is not checked, so TREE's rest flow must be one this core runs alike
(session 21's stays underdamped, where the two agree).
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


if __name__ == "__main__":
    main()
