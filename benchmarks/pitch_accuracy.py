"""Asked vs heard: notes solved by `bowsynth.music.tuning` and rendered for 2 s, the pitch measured by interpolated zero
crossings over the steady second half.

    PYTHONPATH=. .venv/bin/python benchmarks/pitch_accuracy.py

Rows with a fixed F_B: the x100 FDM (the truth) and the audio-rate FDM (its dispersion raises high notes). Rows with
F_B / w = 100 / (2 pi 100) and v_B 0.2 (F_B = that times 2 pi f0): the shipped paper-fb100 operator plays them too.
The column "unsolved" is f0 = the asked pitch (no solve): how flat the friction makes the note. The last two columns
are what `render --pitch` plays: the note solved again with the sounding ratio of the engine that renders it
(`music.engine_tuning.ratio_for_engine`: the audio-rate FDM's own, dispersion included; the operator model's own;
the operator in windows locked to the physics' period, `render --windows physics`: the physics' where the model holds
it), heard from that engine (the target: within 0.1 cent, 65-1000 Hz).
"""

import math
import time

from bowsynth import Scene
from bowsynth.api import render as api_render
from bowsynth.metrics import cents, f0_estimate
from bowsynth.engines import render
from bowsynth.music.engine_tuning import ratio_for_engine
from bowsynth.music.notes import note_name, parse_pitch
from bowsynth.music.tuning import sounding_pitch, tune

FIXED = [("C2", 40.0, 0.1), ("A2", 1000.0, 0.2), ("E3", 100.0, 0.25), ("A4", 100.0, 0.2), ("E5", 300.0, 0.25),
         ("A5", 1000.0, 0.15), ("B5", 1000.0, 0.2)]
PAPER_BETA = 100 / (2 * math.pi * 100)
BETA = ["C2", "G2", "D3", "A3", "A4", "E5", "A5", "B5"]


def heard(sc, engine="fdm", oversample=1, windows="free"):
    if engine == "fdm":
        r = render(sc, engine=engine, oversample=oversample)
    else:
        r = api_render(sc, engine=engine, windows=windows)
    return f0_estimate(r.q, sc.sample_rate, tail=0.5)


def engine_tuned(p, fb, vb, beta, sc, engine, windows="free"):
    """The note as `render --pitch [--windows W]` plays it with this engine: tuned with that engine's ratio in those
    windows, heard from it."""
    ratio, why = ratio_for_engine(sc, engine, windows=windows)
    if ratio is None:
        return f"not played ({why})"
    t = tune(p, fb, vb, beta=beta, ratio=ratio)
    return f"{cents(heard(Scene(f0=t.f0, fb=t.fb, vb=vb, duration=2.0), engine, windows=windows), p):+.3f}"


def main():
    print("| note | asked (Hz) | F_B | F_B / w | v_B | solved f0 (Hz) | solve (s) | FDM x100 (cents) | FDM x1 (cents) "
          "| operator (cents) | f0 = pitch, unsolved (cents) | tuned for FDM x1: heard (cents) | tuned for the operator: "
          "heard (cents) | ... in physics windows: heard (cents) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    rows = [(n, fb, vb, None) for n, fb, vb in FIXED] + [(n, None, 0.2, PAPER_BETA) for n in BETA]
    for name, fb, vb, beta in rows:
        p = parse_pitch(name)
        t0 = time.perf_counter()
        t = tune(p, fb, vb, beta=beta)
        solve = time.perf_counter() - t0
        sc = Scene(f0=t.f0, fb=t.fb, vb=vb, duration=2.0)
        truth = cents(heard(sc, oversample=100), p)
        x1 = cents(heard(sc), p)
        op = f"{cents(heard(sc, 'operator'), p):+.3f}" if beta is not None else "-"
        flat = cents(sounding_pitch(p, t.fb if beta is None else beta * 2 * math.pi * p, vb), p)
        by = [engine_tuned(p, fb, vb, beta, sc, e, w) for e, w in (("fdm", "free"), ("operator", "free"),
                                                                    ("operator", "physics"))]
        print(f"| {note_name(p)} | {p:.2f} | {t.fb:.4g} | {t.beta:.4f} | {vb:g} | {t.f0:.3f} | {solve:.2f} | "
              f"{truth:+.4f} | {x1:+.3f} | {op} | {flat:+.1f} | {by[0]} | {by[1]} | {by[2]} |")


if __name__ == "__main__":
    main()
