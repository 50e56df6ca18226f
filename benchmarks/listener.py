"""What a listener hears, out of sample, over the playing space: timbre, pitch and onset first, NMSE beside.

    PYTHONPATH=. .venv/bin/python benchmarks/listener.py [--model PATH] [--region soft|stick|all] [--n N] [--seed S]
                                                          [--seconds 2] [--json out.json] [--box B0:B1,V0:V1]
                                                          [--windows auto|locked|free|physics]
    PYTHONPATH=. .venv/bin/python benchmarks/listener.py --gestures [--only TEXT] [--model PATH] [--windows auto]

Random bows (F_B / w log-uniform, v_B uniform) at random pitches (f0 log-uniform 65-880 Hz), drawn with a seed no
training uses, each rendered 2 s from rest by the operator (the model the renderer picks, or --model) and by the
audio-rate FDM, both against a x100 FDM at the same f0 and bow (the truth). Per note: harmonics 2-10 of p above -50 dB
re the fundamental, each signal fitted at its own pitch over the last second (dB error), the pitch over the last
second (cents), the onset (first time a one-period RMS reaches half its final value; ms), NMSE(p) over the note.
Summary: notes the operator plays (a covering model, a finished rollout), the median and worst harmonic error over
all scored (note, harmonic) pairs, the median and worst |cents|, onsets within max(5 ms, 2 % of the truth's), and the
same for the audio-rate FDM.
"""

from __future__ import annotations

import argparse
import json
import math
import time
import warnings

import numpy as np

from bowsynth import BowsynthError, Scene
from bowsynth.metrics import frame_errors, listener_errors, nmse, note_sounds, onset_limit_ms
from bowsynth.api import render

REGIONS = {  # (F_B / w lo, hi), (v_B lo, hi): the soft-bow and stick-slip spaces
    "soft": ((0.02, 0.38), (0.09, 0.26)),
    "stick": ((0.65, 1.9), (0.09, 0.26)),
}
PITCH_RANGE = (65.0, 880.0)
REF = 100


def draw(region: str, n: int, seed: int) -> list[tuple[float, float, float]]:
    """n (f0, F_B / w, v_B) triples in a region."""
    (blo, bhi), (vlo, vhi) = REGIONS[region]
    rng = np.random.default_rng(seed)
    f0 = np.exp(rng.uniform(math.log(PITCH_RANGE[0]), math.log(PITCH_RANGE[1]), n))
    beta = np.exp(rng.uniform(math.log(blo), math.log(bhi), n))
    vb = rng.uniform(vlo, vhi, n)
    return [(float(a), float(b), float(c)) for a, b, c in zip(f0, beta, vb)]


def onset_ok(err_ms: float, ref_ms: float) -> bool:
    return math.isfinite(err_ms) and abs(err_ms) <= onset_limit_ms(ref_ms)


WINDOWS = None  # the operator's windows (--windows); None: the render's default, as a user hears it


def one(f0: float, beta: float, vb: float, seconds: float, model=None) -> dict:
    sc = Scene(f0=f0, fb=beta * 2 * math.pi * f0, vb=vb, duration=seconds)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        truth = render(sc, engine="fdm", oversample=REF)
        fdm = render(sc, engine="fdm")
    # a bow whose truth does not sound (held below vb_stop: it rests) scores nothing but whether each engine rests too
    row = {"f0": f0, "beta": beta, "vb": vb, "silent": not note_sounds(truth.p),
           "fdm": listener_errors(fdm.p, truth.p, sc.sample_rate)}
    row["fdm"]["nmse"] = nmse(fdm.p, truth.p)
    row["fdm"]["sounds"] = note_sounds(fdm.p)
    t0 = time.perf_counter()
    try:
        op = render(sc, engine="operator", model=model, windows=WINDOWS)
    except BowsynthError as e:
        row["op"] = None
        row["why"] = str(e).splitlines()[0][:160]
        return row
    row["op_seconds"] = time.perf_counter() - t0
    row["op"] = listener_errors(op.p, truth.p, sc.sample_rate)
    row["op"]["nmse"] = nmse(op.p, truth.p)
    row["op"]["sounds"] = note_sounds(op.p)
    info = op.info
    row["model"] = info.get("model_id") if isinstance(info, dict) else getattr(info, "model_id", None)
    return row


GESTURES = {  # name: (f0, F_B / w curve, v_B curve, seconds), curves as (t, value) breakpoints
    "bow speed 0.12 -> 0.25": (220.0, 0.15, [(0.5, 0.12), (1.5, 0.25)], 2.0),
    "soft crescendo": (100.0, [(0.3, 0.05), (1.8, 0.35)], 0.15, 2.0),
    "crescendo into stick-slip": (100.0, [(0.3, 0.1), (1.8, 1.2)], 0.2, 2.0),
    "bow stop to v_B 0": (150.0, 0.15, [(1.0, 0.2), (1.1, 0.0)], 1.6),
    "attack from F_B 0": (100.0, [(0.0, 0.0), (0.05, 0.2)], 0.2, 1.5),
    "stick-slip bow stop": (100.0, 1.0, [(1.0, 0.2), (1.1, 0.0)], 1.6),  # a stick-slip note's release
    # the heavy forces' releases, the paper's stick-slip scene (F_B 1000 at f0 100) and near the space's edge
    "heavy bow stop (F_B 1000)": (100.0, 1000 / (2 * math.pi * 100), [(1.0, 0.2), (1.1, 0.0)], 1.6),
    "heaviest bow stop": (150.0, 1.9, [(1.0, 0.15), (1.05, 0.0)], 1.6),
    # at the space's edge, where the stop crosses three tiles (stick-heavy, floor-long, halt-edge)
    "bow stop at the edge (F_B / w 2)": (440.0, 2.0, [(1.0, 0.12), (1.05, 0.0)], 1.6),
}
def gesture(name: str, model=None) -> dict:
    f0, beta, vb, seconds = GESTURES[name]
    w = 2 * math.pi * f0
    fb = [(t, b * w) for t, b in beta] if isinstance(beta, list) else beta * w
    sc = Scene(f0=f0, fb=fb, vb=vb, duration=seconds)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        truth = render(sc, engine="fdm", oversample=REF)
        fdm = render(sc, engine="fdm")
    row = {"gesture": name, "fdm": frame_errors(fdm.p, truth.p, sc.sample_rate)}
    try:
        op = render(sc, engine="operator", model=model, windows=WINDOWS)
    except BowsynthError as e:
        row["op"], row["why"] = None, str(e).splitlines()[0][:200]
        return row
    row["op"] = frame_errors(op.p, truth.p, sc.sample_rate)
    row["op"]["nmse"] = nmse(op.p, truth.p)
    return row


def summary(rows: list[dict], key: str) -> dict:
    """The engine's errors over the played bows whose truth sounds; 'silent' how many bows' truth rests, 'wrong' at
    how many of those the engine sounds."""
    silent = [r for r in rows if r.get("silent") and r.get(key)]
    wrong = sum(1 for r in silent if r[key].get("sounds"))
    done = [r for r in rows if r.get(key) and not r.get("silent")]
    harm = [h for r in done for h in r[key]["harm_db"] if h is not None and math.isfinite(h)]
    missing = sum(1 for r in done if not math.isfinite(r[key]["harm_db_max"]))
    cents = [abs(r[key]["cents"]) for r in done if math.isfinite(r[key]["cents"])]
    onsets = [onset_ok(r[key]["onset_err_ms"], r[key]["onset_ref_ms"]) for r in done]
    return {"played": len(done) + len(silent), "of": len(rows), "silent": len(silent), "wrong": wrong,
            "harm_db_median": float(np.median(harm)) if harm else float("nan"),
            "harm_db_max": float("inf") if missing else (float(np.max(harm)) if harm else float("nan")),
            "cents_median": float(np.median(cents)) if cents else float("nan"),
            "cents_max": float(np.max(cents)) if cents else float("nan"),
            "onsets_ok": int(sum(onsets)),
            "nmse_median": float(np.median([r[key]["nmse"] for r in done])) if done else float("nan")}


def fmt(s: dict) -> str:
    rests = f" ({s['silent']} rest, {s['wrong']} of them sounding)" if s["silent"] else ""
    return (f"{s['played']}/{s['of']}{rests} | {s['harm_db_median']:.3g} / {s['harm_db_max']:.3g} | "
            f"{s['cents_median']:.3g} / {s['cents_max']:.3g} | {s['onsets_ok']}/{s['played'] - s['silent']} | "
            f"{s['nmse_median']:.2g}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default=None, help="a model file or name (default: the renderer's choice)")
    ap.add_argument("--region", default="all", choices=["soft", "stick", "all"])
    ap.add_argument("--box", default=None, metavar="BLO:BHI,VLO:VHI",
                    help="held bows drawn from this box of F_B / w and v_B instead (a tile's own, say)")
    ap.add_argument("--n", type=int, default=12, help="bows per region")
    ap.add_argument("--seed", type=int, default=2026)
    ap.add_argument("--seconds", type=float, default=2.0)
    ap.add_argument("--gestures", action="store_true", help="the gestures instead of held bows")
    ap.add_argument("--only", default=None, metavar="TEXT", help="with --gestures: those whose name holds TEXT")
    ap.add_argument("--json", default=None)
    ap.add_argument("--windows", default=None, choices=["locked", "free", "physics", "auto"],
                    help="the operator's windows (render --windows; default the render's, auto; gestures play free "
                         "windows either way)")
    a = ap.parse_args(argv)
    global WINDOWS
    WINDOWS = a.windows
    model = None
    if a.model:
        from bowsynth.api import load_model, model_path

        model = load_model(model_path(a.model))
    out = {"args": vars(a), "regions": {}}
    if a.gestures:
        print("| gesture | engine | frames | harmonics median / worst frame (dB) | pitch median (cents) |")
        print("|---|---|---|---|---|")
        out["gestures"] = []
        for name in [g for g in GESTURES if a.only is None or a.only in g]:
            row = gesture(name, model)
            out["gestures"].append(row)
            for key, label in (("op", "operator"), ("fdm", "audio-rate FDM")):
                g = row[key]
                if g is None:
                    print(f"| {name} | {label} | not played: {row['why'][:90]} | | |")
                else:
                    print(f"| {name} | {label} | {g['frames']} | {g['harm_db_median']:.3g} / "
                          f"{g['harm_db_worst_frame']:.3g} | {g['cents_median']:.3g} |")
        if a.json:
            with open(a.json, "w") as f:
                json.dump(out, f, indent=1, default=str)
        return
    regions = list(REGIONS) if a.region == "all" else [a.region]
    if a.box:
        (blo, bhi), (vlo, vhi) = ([float(x) for x in part.split(":")] for part in a.box.split(","))
        REGIONS[a.box] = ((blo, bhi), (vlo, vhi))
        regions = [a.box]
    print("| region | engine | played | harmonics median / worst (dB) | pitch median / worst (cents) | onsets ok | "
          "NMSE(p) median |")
    print("|---|---|---|---|---|---|---|")
    for reg in regions:
        rows = [one(f0, b, v, a.seconds, model) for f0, b, v in draw(reg, a.n, a.seed)]
        s_op, s_fdm = summary(rows, "op"), summary(rows, "fdm")
        out["regions"][reg] = {"rows": rows, "operator": s_op, "fdm": s_fdm}
        print(f"| {reg} | operator | {fmt(s_op)} |")
        print(f"| {reg} | audio-rate FDM | {fmt(s_fdm)} |")
        for r in rows:
            if r.get("op") is None:
                print(f"  not played: f0 {r['f0']:.1f} F_B/w {r['beta']:.3f} v_B {r['vb']:.3f}: {r.get('why')}")
    if a.json:
        with open(a.json, "w") as f:
            json.dump(out, f, indent=1, default=lambda x: None if isinstance(x, float) and not math.isfinite(x) else x)


if __name__ == "__main__":
    main()
