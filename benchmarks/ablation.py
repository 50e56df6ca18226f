"""Ablations: what each technique buys, one config per row, each trained for the same wall-clock budget.

    .venv/bin/python benchmarks/ablation.py --minutes 2.5

prints the Markdown table in docs/BENCHMARKS.md ("Ablations"; each row's record as JSON on stderr); 12 rows of
2.5 minutes each, about 35 minutes. Each row changes one thing from the default and reports the model's validation:
NMSE(p) of a 1 s rollout from rest against a x100 FDM, and the pitch error in cents. One run per row (seed 0):
differences under about 2x are noise.
"""

import argparse
import copy
import json
import sys
import time

from bowsynth import Scene
from bowsynth.training import TrainConfig, Trainer, default_weights, validate

ABLATIONS = {
    100: [
        ("default: SOAP, scene band, hybrid, fric 0.03, window 2 pi", {}),
        ("Adam instead of SOAP", {"optimizer": "adam", "lr": 2e-3}),
        ("box sampling instead of the scene's band", {"sampling": "box"}),
        ("pure physics-informed (--no-hybrid)", {"hybrid": False}),
        ("no exact linear flow in the output", {"net.linear_flow": False}),
        ("window pi (5 ms at 100 Hz)", {"window": 3.141592653589793}),
        ("no data windows at the render's own window starts", {"start_share": 0.0}),
        ("friction residual weight 0.3", {"weights": {"data": 1, "end": 1, "kin": 1, "fric": 0.3}}),
        ("L-BFGS finish on the last 30 %", {"lbfgs_fraction": 0.3}),
    ],
    1000: [
        ("default: SOAP, scene band, data + end + kinematic residual", {}),
        ("friction residual at equal weight", {"weights": {"data": 1, "end": 1, "kin": 1, "fric": 1}}),
        ("pure physics-informed (--no-hybrid)", {"hybrid": False}),
    ],
}


def run(fb: float, label: str, changes: dict, minutes: float) -> dict:
    cfg = TrainConfig(minutes=minutes)
    for k, v in changes.items():
        if k.startswith("net."):
            setattr(cfg.net, k[4:], v)
        else:
            setattr(cfg, k, copy.deepcopy(v))
    sc = Scene(fb=fb)
    t0 = time.perf_counter()
    tr = Trainer(sc, cfg, "ablation")
    tr.run()
    model = tr.model()
    v = validate(model, sc)
    return {"fb": fb, "label": label, "weights": cfg.weights or default_weights(sc, cfg.hybrid), "steps": tr.step,
            "train_s": round(time.perf_counter() - t0), "nmse_p_1s": v.get("nmse"), "cents": v.get("cents"),
            "error": v.get("error")}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--minutes", type=float, default=2.5)
    ap.add_argument("--fb", type=float, nargs="*", default=[100, 1000])
    args = ap.parse_args()
    rows = []
    print("| fb | change from the default | steps | NMSE(p) 1 s | pitch error (cents) |")
    print("|---|---|---|---|---|")
    for fb in args.fb:
        for label, changes in ABLATIONS[int(fb)]:
            r = run(fb, label, changes, args.minutes)
            rows.append(r)
            score = f"{r['nmse_p_1s']:.2e}" if r["nmse_p_1s"] is not None else f"failed: {r['error'][:60]}"
            cents = f"{r['cents']:+.3f}" if r["cents"] is not None else "n/a"
            print(f"| {fb:g} | {label} | {r['steps']} | {score} | {cents} |", flush=True)
    json.dump(rows, sys.stderr, indent=1)


if __name__ == "__main__":
    main()
