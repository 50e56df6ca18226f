"""How long a training prepares its data (the FDM trajectories of training.data, before the first step), with the
batch FDM in the compiled loop (fdm_batch's default) and in numpy (its reference), for shipped recipes.

    PYTHONPATH=. .venv/bin/python benchmarks/train_data.py [--recipes paper-fb100,soft-range,stick-heavy]

Each recipe is read as `bowsynth train --config` reads it; the data are built twice and compared to the bit.
Results: docs/BENCHMARKS.md, "Training data in the compiled loop".
"""

from __future__ import annotations

import argparse
import functools
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


def prepare(recipe: Path, loop: str):
    from bowsynth.cli.train import _scene_and_box, _train_config
    from bowsynth.engines import fdm
    from bowsynth.training import Trainer, data
    from bowsynth.training.recipe import load_recipe

    r = load_recipe(recipe)
    scene, box = _scene_and_box(r.get("preset"), r.get("f0"), r.get("fb"), r.get("vb"), r.get("a"), None, None,
                                None, None)
    cfg = _train_config(scene, box, minutes=r.get("minutes"), seed=r.get("seed"), width=r.get("width"),
                        window_ms=r.get("window_ms"), rest_linear=r.get("rest_linear"))
    original = data.fdm_batch
    data.fdm_batch = functools.partial(fdm.fdm_batch, loop=loop)
    try:
        t0 = time.perf_counter()
        tr = Trainer(scene, cfg, "bench", box=box)
        return time.perf_counter() - t0, tr.data
    finally:
        data.fdm_batch = original


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--recipes", default="paper-fb100,soft-range,stick-heavy")
    args = ap.parse_args()
    print("| recipe | trajectories x steps | numpy (s) | compiled (s) | same to the bit |")
    print("|---|---|---|---|---|")
    for name in args.recipes.split(","):
        path = ROOT / "models" / f"{name}.toml"
        t_core, d_core = prepare(path, "core")
        t_np, d_np = prepare(path, "numpy")
        same = np.array_equal(d_core.x, d_np.x)
        print(f"| {name} | {d_core.x.shape[0]} x {d_core.x.shape[1]} | {t_np:.1f} | {t_core:.1f} | {same} |",
              flush=True)


if __name__ == "__main__":
    main()
