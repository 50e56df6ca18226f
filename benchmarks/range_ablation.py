"""Ablations of the range model's choices, one config per row: each row trains a range model on the same box for
the same minutes (one at a time: they share the 2 cores) and scores the 4 x 4 held-out grid at f0 100, 1 s from rest
against the FDM x100 (bench.bench_parameter_points).

    PYTHONPATH=. .venv/bin/python benchmarks/range_ablation.py [--minutes 10] [--rows base,no_corr_beta] [--box stick]

--box stick: the stick-slip range box (F_B / w 0.6-2.0, v_B 0.1-0.3) instead of the soft one below, scored on
its validation grid (9 bows, with the failures named) as well.

Rows (TrainConfig fields changed from the defaults):
    base           the shipped recipe
    no_corr_beta   the correction not scaled by beta / beta_ref (range_corr_beta False)
    no_gestures    band from renders at fixed bows only (range_gestures 0)
    no_starts      no window-start data (start_share 0)
    bow_scaled     the state scaled per bow, fitted to the renders' limit cycles (range_bow_scaled True)
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from bowsynth import api
from bowsynth.analysis.out_of_sample import bench_parameter_points, parameter_summary
from bowsynth.training.ranges import ParamBox

BOX = ParamBox(0.08, 0.32, 0.1, 0.28, 100.0)  # the box of the first range measurement
STICK = ParamBox.from_forces((376.9, 1256.7), (0.1, 0.3), 100.0, 100.0)  # F_B / w 0.6-2.0 at f0 100
ROWS = {
    "base": {},
    "no_corr_beta": {"range_corr_beta": False},
    "no_gestures": {"range_gestures": 0},
    "no_starts": {"start_share": 0.0},
    "bow_scaled": {"range_bow_scaled": True},
}


def main(argv):
    minutes = float(argv[argv.index("--minutes") + 1]) if "--minutes" in argv else 10.0
    names = argv[argv.index("--rows") + 1].split(",") if "--rows" in argv else list(ROWS)
    box = STICK if "--box" in argv and argv[argv.index("--box") + 1] == "stick" else BOX
    out_dir = Path("/tmp/bowsynth-range-ablation")
    out_dir.mkdir(exist_ok=True)
    print(f"box {box.describe()}, {minutes:g} min each, held-out 4 x 4 grid at f0 100, 1 s from rest vs FDM x100")
    print("| row | config change | steps | median NMSE(p) | worst NMSE(p) | worst cents | FDM fallbacks |")
    print("|---|---|---|---|---|---|---|")
    for name in names:
        sc = api.range_scene(box)
        cfg = api.make_train_config(sc, minutes=minutes, **ROWS[name])
        t0 = time.time()
        res = api.train(sc, config=cfg, out=out_dir / f"{name}.safetensors", force=True, box=box)
        if box is STICK:
            v = res.model.meta.validation
            print(f"  {name}: validation {v.get('error') or ''} median {v.get('nmse')}, worst {v.get('nmse_max')}")
        s = parameter_summary(bench_parameter_points(res.model))
        print(f"| {name} | {ROWS[name] or 'none'} | {res.model.meta.training['steps_done']} | {s['median_nmse']:.2e} | "
              f"{s['worst_nmse']:.2e} | {s['worst_cents']:.3f} | {s['fdm_fallbacks']} |  ({time.time() - t0:.0f} s)",
              flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
