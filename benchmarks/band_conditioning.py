"""How well conditioned the pitch is near vb_stop: the truth's sounding ratio (tuning.sounding_ratio, the reference
integration `--pitch` tunes with) at each bow of a grid against the same bow with v_B (then F_B / w) moved by a
relative share, both signs; the worse sign's |cents| per share.

    PYTHONPATH=. .venv/bin/python benchmarks/band_conditioning.py [--betas 1.0,1.2,...] [--vbs 0.07075,...]
                                                                  [--rel 0.001] [--bows F0:BETA:VB,...]
    PYTHONPATH=. .venv/bin/python benchmarks/band_conditioning.py --models MODEL:F0:BETA:VB,...

The pitch target (1 cent worst) holds where a bow 0.1 % off moves the pitch 0.3-1.2 cents (docs/measures.md):
a target a model meets by knowing its bow to ~0.1 %. Just above vb_stop = 1 / sqrt(2a) the pitch moves far faster
with v_B (the creep before each slip lengthens without bound as v_B falls to vb_stop), and this table says how much:
a miss there reads as the bow error that would cause it (--bows: each bow's cents per 0.1 % at its own bow).

--models reads a model's accuracy the same way, before any listening: its one-window error on the truth's limit cycle
at the bow (what its training's end term measures) against the one-window difference the FDM makes for v_B moved by
1e-4 of itself (which grows as the square of the move: measured), so the v_B error its error equals; the cents that
bow error moves the truth's pitch by (the worse sign); and the model's own note from rest (2 s against a x100 FDM)
in free windows (the pitch the network keeps itself: the miss the error predicts) and in auto (what a render plays).
"""

from __future__ import annotations

import argparse
import math

from bowsynth.errors import BowsynthError
from bowsynth.music.tuning import SilentNoteError, sounding_ratio

A = 100.0


def cents_per(beta: float, vb: float, rel: float, which: str) -> float | None:
    """The worse of +/- rel in v_B (which 'vb') or F_B / w ('beta'): |cents| of the truth's pitch; None where a
    moved bow rests or the bow itself does."""
    try:
        r0 = sounding_ratio(beta, vb, A).r
        worst = 0.0
        for s in (1, -1):
            b, v = (beta * (1 + s * rel), vb) if which == "beta" else (beta, vb * (1 + s * rel))
            worst = max(worst, abs(1200 * math.log2(sounding_ratio(b, v, A).r / r0)))
        return worst
    except SilentNoteError:
        return None


def model_row(path: str, f0: float, beta: float, vb: float) -> dict:
    """One --models row (see the module docstring). Torch for the model's one-window map (a benchmark, not a render)."""
    import numpy as np
    import torch

    from bowsynth import Scene
    from bowsynth.metrics import listener_errors
    from bowsynth.api import render
    from bowsynth.engines.fdm import render_fdm
    from bowsynth.engines.operator.modelfile import load_model
    from bowsynth.training.data import fdm_windows

    m = load_model(path)
    sc = Scene(f0=f0, fb=beta * 2 * math.pi * f0, vb=vb, a=A, duration=2.0)
    r = render_fdm(sc, oversample=4)
    start = np.stack([r.q, r.p], 1)[int(1.5 * sc.sample_rate)::7][:128]  # a few periods of the steady note
    w, par = float(m.domain.window), np.tile([beta, vb], (len(start), 1))
    end = {d: fdm_windows(sc, start, w, 64, 40, par=par + [0.0, d])[1][:, -1] for d in (0.0, 1e-4 * vb)}
    with torch.no_grad():
        p = torch.tensor(par, dtype=torch.float32)
        net = m.net
        gain = net.gain(p)
        scale = (net.corr_scale if gain is None else net.corr_scale * gain[:, None]).numpy()
        pred = net(torch.tensor(start, dtype=torch.float32), torch.tensor([w], dtype=torch.float32), p)[:, -1].numpy()
    mse = lambda a, b: float(np.median((((a - b) / scale) ** 2).mean(1)))  # noqa: E731
    err, ref = mse(pred, end[0.0]), mse(end[1e-4 * vb], end[0.0])
    d_eq = 1e-4 * math.sqrt(err / ref)  # relative to v_B
    try:
        r0, worst = sounding_ratio(beta, vb, A).r, 0.0
        for s in (1, -1):
            worst = max(worst, abs(1200 * math.log2(sounding_ratio(beta, vb * (1 + s * d_eq), A).r / r0)))
    except SilentNoteError:
        worst = None
    truth = render(sc, engine="fdm", oversample=100).p
    cents = [listener_errors(render(sc, model=m, windows=win).p, truth, sc.sample_rate)["cents"]
             for win in ("free", "auto")]
    return {"err": err, "d_eq": d_eq, "cents_eq": worst, "free": cents[0], "auto": cents[1]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--betas", default="1.0,1.2,1.4,1.6,1.8,1.95")
    ap.add_argument("--vbs", default="0.07075,0.0708,0.0709,0.071,0.0715,0.072,0.073,0.074,0.076,0.1,0.15,0.2")
    ap.add_argument("--rel", type=float, default=0.001)
    ap.add_argument("--bows", default="", help="F0:BETA:VB[:CENTS],...: the cents per --rel at each (and CENTS, a "
                                                "miss there, as the bow error in % that would cause it)")
    ap.add_argument("--models", default="", help="MODEL:F0:BETA:VB,...: each model's one-window error at the bow as "
                                                  "a v_B error, the cents that moves the truth by, its note's cents")
    args = ap.parse_args()
    fmt = lambda x: "rests" if x is None else f"{x:.2f}"  # noqa: E731
    if args.models:
        print("| model | f0 | F_B / w | v_B | one-window error (median mse, its correction scale) | as a v_B error | "
              "the truth's pitch moved by it (cents) | its note from rest, free / auto windows (cents) |\n"
              "|---|---|---|---|---|---|---|---|")
        for item in args.models.split(","):
            path, f0, beta, vb = item.rsplit(":", 3)
            name = path.rsplit("/", 1)[-1].removesuffix(".safetensors")
            try:
                row = model_row(path, float(f0), float(beta), float(vb))
            except BowsynthError as e:  # a box that does not hold the bow, a note that leaves the model's states
                print(f"| {name} | {f0} | {beta} | {vb} | {str(e).splitlines()[0][:90]} | | | |", flush=True)
                continue
            print(f"| {name} | {f0} | {beta} | {vb} | {row['err']:.2g} | "
                  f"{row['d_eq']:.3%} | {fmt(row['cents_eq'])} | {row['free']:+.2f} / {row['auto']:+.2f} |",
                  flush=True)
        return
    if args.bows:
        print(f"| f0 | F_B / w | v_B | cents per {args.rel * 100:g} % of v_B | of F_B / w | miss (cents) | "
              f"as a bow error (v_B) |\n|---|---|---|---|---|---|---|")
        for item in args.bows.split(","):
            f0, beta, vb, *miss = (float(x) for x in item.split(":"))
            cv, cb = cents_per(beta, vb, args.rel, "vb"), cents_per(beta, vb, args.rel, "beta")
            eq = f"{miss[0] / cv * args.rel:.3%}" if miss and cv else ""
            print(f"| {f0:g} | {beta:g} | {vb:g} | {fmt(cv)} | {fmt(cb)} | {miss[0] if miss else ''} | {eq} |",
                  flush=True)
        return
    betas = [float(b) for b in args.betas.split(",")]
    print(f"|cents| of the truth's pitch for v_B moved {args.rel * 100:g} % (the worse sign) / for F_B / w moved "
          f"as much\n")
    print("| v_B \\ F_B / w | " + " | ".join(f"{b:g}" for b in betas) + " |\n|---|" + "---|" * len(betas))
    for vb in (float(v) for v in args.vbs.split(",")):
        cells = [f"{fmt(cents_per(b, vb, args.rel, 'vb'))} / {fmt(cents_per(b, vb, args.rel, 'beta'))}"
                 for b in betas]
        print(f"| {vb:g} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
