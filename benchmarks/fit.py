"""bowsynth fit against hidden bows: targets rendered by a x100 FDM from random held bows over the playing space
(f0 65-880 Hz, 2 s from rest, written as `render` writes files), each fitted as `bowsynth fit` does (api.fit), and
beside it CMA-ES (the `cma` package) from the same start on the same loss until it reaches the gradient descent's loss
or spends four times its notes.

    .venv/bin/python benchmarks/fit.py --n 6 --seed 8301
    .venv/bin/python benchmarks/fit.py --draws 8301:5,8302:8   # two draws in one table (docs/fit.md)
    .venv/bin/python benchmarks/fit.py --gestures      # a crescendo, a bow-speed change, a stop, fitted as curves
    .venv/bin/python benchmarks/fit.py --n 5 --seed 8301 --fdm   # and the fit through the FDM beside it

Per target: the bow's error (F_B / w, v_B, %) and whether the fit called each part identifiable, the fitted note
against the target as its written score plays it (the fit's model and windows: harmonics median dB, pitch cents,
onset ms), the fit's seconds, and the descent's and CMA-ES's seconds and losses from the same start.
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bowsynth import BowsynthError, api  # noqa: E402
from bowsynth.fit.search import BETA_RANGE, VB_UNIT, Candidate, Scorer, descend, f0_for  # noqa: E402
from bowsynth.fit.surrogate import note_scene  # noqa: E402
from bowsynth.fit.target import read_target  # noqa: E402
from bowsynth.io.audio import write_wav  # noqa: E402
from bowsynth.music.ratio_map import physics_ratio  # noqa: E402


def draw(rng) -> tuple[float, float, float]:
    """A sounding held bow: f0 log-uniform 65-880 Hz, F_B / w log-uniform 0.02-2, v_B uniform 0.08-0.28."""
    while True:
        f0 = float(np.exp(rng.uniform(np.log(65), np.log(880))))
        beta = float(np.exp(rng.uniform(np.log(0.02), np.log(2.0))))
        vb = float(rng.uniform(0.08, 0.28))
        try:
            physics_ratio(beta, vb, 100.0)
        except Exception:  # noqa: BLE001 - a bow that does not sound: draw again
            continue
        return f0, beta, vb


def bow_of(x) -> tuple[float, float]:
    """A point of the search, (log F_B / w, v_B / VB_UNIT), as the bow (F_B / w, v_B)."""
    return float(np.clip(math.exp(x[0]), *BETA_RANGE)), float(x[1]) * VB_UNIT


def cma_search(value, x0, best: float, max_evals: int, target: float = -math.inf) -> tuple[list, float, int]:
    """CMA-ES (the `cma` package, step 0.1, seed 1) of value(x) from x0, whose loss is `best`: (the best point, its
    loss, the points scored) once the loss reaches `target` or max_evals points are scored."""
    import cma

    es = cma.CMAEvolutionStrategy(list(x0), 0.1, {"verbose": -9, "seed": 1, "maxfevals": max_evals})
    best_x, n = list(x0), 0
    while not es.stop() and best > target and n < max_evals:
        xs = es.ask()
        fs = [value(x) for x in xs]
        n += len(xs)
        es.tell(xs, fs)
        i = int(np.argmin(fs))
        if fs[i] < best:
            best, best_x = fs[i], xs[i]
    return best_x, best, n


def fdm_fit(t, start, oversample: int = 4, max_evals: int = 160) -> tuple[float, float, float, int, float]:
    """The fit through the FDM (the baseline where feasible): CMA-ES over (log F_B / w, v_B) from `start` (the
    operator fit's bow), each candidate rendered by the FDM at `oversample` x the target's rate with f0 from the
    target's pitch and the shipped map, scored by the same loss. (F_B / w, v_B, loss, renders, seconds)."""
    from bowsynth.fit.loss import SoundLoss

    loss = SoundLoss(t.x, t.sample_rate)
    seconds = t.n / t.sample_rate

    def value(x) -> float:
        beta, vb = bow_of(x)
        f0 = f0_for(loss.pitch, beta, vb)
        if f0 is None:  # a bow that does not sound: the worst score
            return 10.0
        try:
            r = api.render_fdm(note_scene(f0, beta, vb, seconds, t.sample_rate), oversample=oversample)
        except BowsynthError:  # a request the FDM refuses: the worst score
            return 10.0
        return loss.value(np.asarray(r.q, float))

    t0 = time.monotonic()
    x0 = [math.log(start.beta), start.vb / VB_UNIT]
    best_x, best, n = cma_search(value, x0, value(x0), max_evals - 1)  # the start is the first render
    return (*bow_of(best_x), best, n + 1, time.monotonic() - t0)


def cma_from(scorer: Scorer, start: Candidate, target_loss: float, max_evals: int) -> tuple[float, float, int]:
    """CMA-ES in u from `start`: (seconds, best loss, notes) until the loss reaches target_loss or max_evals."""
    def value(x) -> float:
        c = scorer.score(*bow_of(x), locked=start.locked)
        return c.loss if c is not None else 10.0

    t0 = time.monotonic()
    _, best, n = cma_search(value, start.u, start.loss, max_evals, target=target_loss)
    return time.monotonic() - t0, best, n


GESTURES = {  # at f0 150, 2 s: (F_B / w, v_B) as numbers or [[t, value], ...]
    "crescendo": ([[0, 0.08], [2.0, 0.3]], 0.2),
    "bow speed": (0.2, [[0, 0.12], [2.0, 0.25]]),
    "stop": (0.8, [[0, 0.2], [1.4, 0.2], [1.7, 0.0]]),
}


def gestures() -> None:
    from bowsynth.scene import Scene

    f0 = 150.0
    w = 2 * math.pi * f0
    tmp = Path(tempfile.mkdtemp(prefix="bowsynth-fit-bench-"))
    print("| gesture | held fit loss | curves loss | F_B / w at 0.1 / 1.0 / 1.9 s (truth) | v_B at 0.1 / 1.0 / 1.9 s "
          "(truth) | harmonics dB per frame (median / worst) | pitch cents per frame | identifiable breakpoints "
          "(F_B / w, v_B) | at the box's edge | s |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name, (beta, vb) in GESTURES.items():
        scale = lambda c, k=1.0: [[t, v * k] for t, v in c] if isinstance(c, list) else c * k  # noqa: E731
        sc = Scene(f0=f0, fb=scale(beta, w), vb=vb, duration=2.0)
        path = tmp / f"{name}.wav"
        write_wav(path, api.render_fdm(sc, oversample=100))
        t0 = time.monotonic()
        f, c = api.fit(path, curves=True)
        at = [np.argmin(np.abs(c.times - x)) for x in (0.1, 1.0, 1.9)]
        tb = [float(sc.fb_at(np.array([c.times[i]]))[0]) / w for i in at]
        tv = [float(sc.vb_at(np.array([c.times[i]]))[0]) for i in at]
        ident = c.identifiable()
        ch = c.checked
        print(f"| {name} | {f.best.loss:.3f} | {c.loss:.3f} | "
              + " / ".join(f"{c.beta[i]:.3f} ({x:.3f})" for i, x in zip(at, tb)) + " | "
              + " / ".join(f"{c.vb[i]:.4f} ({x:.4f})" for i, x in zip(at, tv))
              + f" | {ch['harmonics_db']:.2f} / {ch['harmonics_db_worst']:.2f} | {ch['pitch_cents']:.2f} | "
              f"{int(ident[:, 0].sum())}, {int(ident[:, 1].sum())} of {len(ident)} | {'yes' if c.at_edge else 'no'} | "
              f"{time.monotonic() - t0:.0f} |", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=6)
    ap.add_argument("--seed", type=int, default=8301)
    ap.add_argument("--gestures", action="store_true")
    ap.add_argument("--fdm", action="store_true", help="also fit through the FDM (x4), from the operator fit's bow")
    ap.add_argument("--draws", default=None, help="several draws in one table: SEED:N,SEED:N (instead of --seed, --n)")
    args = ap.parse_args()
    if args.gestures:
        gestures()
        return
    draws = ([tuple(int(x) for x in d.split(":")) for d in args.draws.split(",")] if args.draws
             else [(args.seed, args.n)])
    tmp = Path(tempfile.mkdtemp(prefix="bowsynth-fit-bench-"))
    print("| f0 | F_B / w | v_B | F_B / w err % (id) | v_B err % (id) | harmonics dB | pitch cents | onset ms | fit s |"
          " descent s / loss | CMA-ES s / loss (notes) |" + (" FDM fit: F_B / w err %, v_B err %, loss (operator's), "
                                                             "renders, s |" if args.fdm else ""))
    print("|---|---|---|---|---|---|---|---|---|---|---|" + ("---|" if args.fdm else ""))
    targets = []
    for seed, n in draws:
        rng = np.random.default_rng(seed)
        targets += [draw(rng) for _ in range(n)]
    for f0, beta, vb in targets:
        path = tmp / f"t-{f0:.1f}-{beta:.3f}-{vb:.3f}.wav"
        write_wav(path, api.render_fdm(note_scene(f0, beta, vb, 2.0, 44100), oversample=100))
        t0 = time.monotonic()
        f = api.fit(path)
        fit_s = time.monotonic() - t0
        b, ch = f.best, f.checked
        # descent vs CMA-ES from the same start: the best bow the zoom found near the fit's (the fit's own, moved 5 %)
        t = read_target(path)
        sc = Scorer(t)
        start = sc.score(b.beta * 1.05, b.vb * 1.02, locked=b.locked) or b
        t1 = time.monotonic()
        ev0 = sc.evaluations
        d = descend(sc, start)
        d_s, d_n = time.monotonic() - t1, sc.evaluations - ev0
        c_s, c_loss, c_n = cma_from(sc, start, d.loss, 4 * max(d_n, 1))
        print(f"| {f0:.1f} | {beta:.4f} | {vb:.4f} | {100 * (b.beta / beta - 1):+.1f} "
              f"({'yes' if f.identifiable('beta') else 'no'}) | {100 * (b.vb / vb - 1):+.2f} "
              f"({'yes' if f.identifiable('vb') else 'no'}) | {ch['harmonics_db']:.2f} | {ch['pitch_cents']:+.3f} | "
              f"{ch['onset_ms']:+.1f} | {fit_s:.1f} | {d_s:.1f} / {d.loss:.4f} | {c_s:.1f} / {c_loss:.4f} ({c_n}) |",
              end="", flush=True)
        if args.fdm:
            fb, fv, fl, fn, fs = fdm_fit(t, b)
            print(f" {100 * (fb / beta - 1):+.2f}, {100 * (fv / vb - 1):+.2f}, {fl:.4f} ({b.loss:.4f}), {fn}, {fs:.0f} |",
                  end="")
        print(flush=True)


if __name__ == "__main__":
    main()
