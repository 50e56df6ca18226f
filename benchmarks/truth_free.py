"""What ships alone, out of sample: random held bows over the whole playing space, each rendered by the operator with
every reference entry point raising (no FDM at any rate, no sounding-ratio solve), from an empty cache, against a
x100 FDM at the same f0 and bow; each bow judged against what the physics can answer there.

    PYTHONPATH=. .venv/bin/python benchmarks/truth_free.py [--n 32] [--seed 7901 | --seeds 7902,7903] [--table]
                                                          [--seconds 2] [--json out.json]
                                                          [--windows auto|free|physics|locked] [--rel 1e-3]

Bows: F_B / w log-uniform over 0.02-2, v_B uniform over 0-0.28, f0 log-uniform over 65-880 Hz. Per bow, the truth's
conditioning s: the most its harmonics 1-10 (dB) and its pitch (cents) move when F_B / w or v_B moves by --rel (0.1 %)
either way (four more x100 renders). A bow meets the worst-case targets when its harmonics are within max(1 dB, s_dB),
its pitch within max(1 cent, s_cents) and its onset within max(5 ms, 2 % of the truth's); the medians are held to
0.2 dB and 0.2 cents. The onset's own conditioning (how far it moves for the same bows) is measured too, and an onset
miss where the truth's onset moves more than the target is counted apart. Printed: a row per bow, then the summary
and the count of bows where s exceeds the target; with --table only the summary table docs/BENCHMARKS.md shows.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import sys
import tempfile
import time
import warnings

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))

from bowsynth import BowsynthError, Scene  # noqa: E402
from bowsynth.metrics import listener_errors, nmse, note_sounds, onset_limit_ms  # noqa: E402
from bowsynth.api import render  # noqa: E402

REF = 100
TARGET_DB, TARGET_CENTS, MEDIAN_DB, MEDIAN_CENTS = 1.0, 1.0, 0.2, 0.2


class ReferenceRan(RuntimeError):
    """A reference entry point was called during the operator's render."""


@contextlib.contextmanager
def no_reference():
    """Every FDM entry point (the compiled loop, its wrapper, the render, the batch, the ratio solve) raises."""
    import bowsynth.compiled as C
    import bowsynth.engines.fdm as F
    import bowsynth.music.tuning as T

    def boom(*a, **k):
        raise ReferenceRan("the reference ran during an operator render")
    saved = [(C, "fdm_run"), (F, "run_fdm_raw"), (F, "render_fdm"), (F, "fdm_batch"), (T, "measure_ratio")]
    old = [getattr(m, n) for m, n in saved]
    for m, n in saved:
        setattr(m, n, boom)
    try:
        yield
    finally:
        for (m, n), f in zip(saved, old):
            setattr(m, n, f)


def draw(n: int, seed: int) -> list[tuple[float, float, float]]:
    rng = np.random.default_rng(seed)
    f0 = np.exp(rng.uniform(math.log(65.0), math.log(880.0), n))
    beta = np.exp(rng.uniform(math.log(0.02), math.log(2.0), n))
    vb = rng.uniform(0.0, 0.28, n)
    return [(float(a), float(b), float(c)) for a, b, c in zip(f0, beta, vb)]


def truth_of(f0, beta, vb, seconds):
    sc = Scene(f0=f0, fb=beta * 2 * math.pi * f0, vb=vb, duration=seconds)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return sc, render(sc, engine="fdm", oversample=REF)


def conditioning(f0, beta, vb, seconds, truth_p, rel) -> tuple[float, float, float]:
    """(s_dB, s_cents, s_onset_ms): the most the truth's harmonics, pitch and onset move for a bow `rel` off in
    F_B / w or v_B."""
    s_db = s_c = s_on = 0.0
    for b, v in ((beta * (1 + rel), vb), (beta * (1 - rel), vb), (beta, vb * (1 + rel)), (beta, vb * (1 - rel))):
        _, moved = truth_of(f0, b, v, seconds)
        if not note_sounds(moved.p):
            return math.inf, math.inf, math.inf  # the note stops speaking a bow 0.1 % off: nothing is determined
        e = listener_errors(moved.p, truth_p, 44100)
        s_db = max(s_db, e["harm_db_max"] if math.isfinite(e["harm_db_max"]) else math.inf)
        s_c = max(s_c, abs(e["cents"]) if math.isfinite(e["cents"]) else math.inf)
        s_on = max(s_on, abs(e["onset_err_ms"]) if math.isfinite(e["onset_err_ms"]) else math.inf)
    return s_db, s_c, s_on


def one(f0, beta, vb, seconds, windows, rel) -> dict:
    sc, truth = truth_of(f0, beta, vb, seconds)
    row = {"f0": f0, "beta": beta, "vb": vb, "silent": not note_sounds(truth.p)}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        fdm = render(sc, engine="fdm")
    row["fdm"] = listener_errors(fdm.p, truth.p, sc.sample_rate)
    t0 = time.perf_counter()
    try:
        with no_reference():
            op = render(sc, engine="operator", windows=windows)
    except (BowsynthError, ReferenceRan) as e:
        row.update(op=None, why=f"{type(e).__name__}: {str(e).splitlines()[0][:150]}")
        return row
    row["op_seconds"] = time.perf_counter() - t0
    row["model"] = os.path.basename(op.info.model_path or "") or op.info.model_id
    row["op"] = {**listener_errors(op.p, truth.p, sc.sample_rate), "nmse": nmse(op.p, truth.p),
                 "sounds": note_sounds(op.p)}
    if not row["silent"]:
        row["s_db"], row["s_cents"], row["s_onset_ms"] = conditioning(f0, beta, vb, seconds, truth.p, rel)
    return row


def judged(r: dict) -> dict:
    e = r["op"]
    lim_db, lim_c = max(TARGET_DB, r["s_db"]), max(TARGET_CENTS, r["s_cents"])
    lim_on = onset_limit_ms(e["onset_ref_ms"])
    err_on = abs(e["onset_err_ms"]) if math.isfinite(e["onset_err_ms"]) else math.inf
    return {"harm_ok": e["harm_db_max"] <= lim_db, "pitch_ok": abs(e["cents"]) <= lim_c,
            "onset_ok": err_on <= lim_on, "onset_ok_conditioned": err_on <= max(lim_on, r["s_onset_ms"]),
            "ill": r["s_db"] > TARGET_DB or r["s_cents"] > TARGET_CENTS, "onset_ill": r["s_onset_ms"] > lim_on}


def summarise(rows: list[dict]) -> dict:
    sounding = [r for r in rows if not r["silent"]]
    played = [r for r in sounding if r["op"] is not None]
    harm = [h for r in played for h in r["op"]["harm_db"] if h is not None and math.isfinite(h)]
    cents = [abs(r["op"]["cents"]) for r in played if math.isfinite(r["op"]["cents"])]
    fdm_c = [abs(r["fdm"]["cents"]) for r in sounding if math.isfinite(r["fdm"]["cents"])]
    ok = [r for r in played if all(r["judged"][k] for k in ("harm_ok", "pitch_ok", "onset_ok"))]
    ok_c = [r for r in played if all(r["judged"][k] for k in ("harm_ok", "pitch_ok", "onset_ok_conditioned"))]
    return {
        "bows": len(rows), "sounding": len(sounding), "played": len(played),
        "silent": len(rows) - len(sounding),
        "rest_ok": sum(1 for r in rows if r["silent"] and (r["op"] is None or not r["op"]["sounds"])),
        "harm_db_median": float(np.median(harm)) if harm else None,
        "cents_median": float(np.median(cents)) if cents else None, "cents_max": max(cents) if cents else None,
        "fdm_cents_median": float(np.median(fdm_c)) if fdm_c else None,
        "within_worst_targets": len(ok), "within_with_onset_conditioning": len(ok_c),
        "ill_conditioned": sum(1 for r in played if r["judged"]["ill"]),
        "onset_ill_conditioned": sum(1 for r in played if r["judged"]["onset_ill"]),
        "render_seconds_median": float(np.median([r["op_seconds"] for r in played])) if played else None,
        "render_seconds_max": max(r["op_seconds"] for r in played) if played else None,
    }


def table_row(seed: int, s: dict) -> str:
    """The summary as a row of the table docs/BENCHMARKS.md shows (TABLE_HEAD)."""
    return (f"| seed {seed} | {s['sounding']} | {s['played']} | {s['rest_ok']} of {s['silent']} | "
            f"{s['harm_db_median']:.3f} dB | {s['cents_median']:.3f} / {s['cents_max']:.2f} cents | "
            f"{s['within_worst_targets']} of {s['sounding']} | {s['ill_conditioned']} |")


TABLE_HEAD = ("| draw | sounding | played by the operator | rests as the truth rests | harmonics median | "
              "pitch median / worst | within every worst-case target | ill (s > target) |\n|---|---|---|---|---|---|---|---|")


def run_draw(a, seed: int, out) -> tuple[list[dict], dict]:
    """Every bow of one draw, a row each printed to `out` as it is judged; (rows, summary)."""
    os.environ["BOWSYNTH_CACHE"] = tempfile.mkdtemp(prefix="truth-free-cache-")  # a cold cache: nothing measured
    rows = []
    print("| f0 | F_B / w | v_B | model | harmonics worst (dB) | pitch (cents) | onset (ms) | s dB / cents / onset | "
          "render (s) | verdict |", file=out)
    print("|---|---|---|---|---|---|---|---|---|---|", file=out)
    for f0, beta, vb in draw(a.n, seed):
        r = one(f0, beta, vb, a.seconds, a.windows, a.rel)
        rows.append(r)
        head = f"| {f0:.1f} | {beta:.4g} | {vb:.4g} |"
        if r["op"] is None:
            print(f"{head} not played: {r['why']} | | | | | | {'rests' if r['silent'] else 'MISS'} |", file=out,
                  flush=True)
            continue
        e = r["op"]
        if r["silent"]:
            verdict = "rests" if not e["sounds"] else "MISS (sounds where the truth rests)"
            print(f"{head} {r['model']} | | | | | {r['op_seconds']:.2f} | {verdict} |", file=out, flush=True)
            continue
        j = r["judged"] = judged(r)
        verdict = "ok" if j["harm_ok"] and j["pitch_ok"] and j["onset_ok"] else (
            "MISS (onset; the truth's moves more)" if j["harm_ok"] and j["pitch_ok"] and j["onset_ok_conditioned"]
            else "MISS")
        print(f"{head} {r['model']} | {e['harm_db_max']:.3g} | {e['cents']:+.3g} | {e['onset_err_ms']:+.3g} | "
              f"{r['s_db']:.2g} / {r['s_cents']:.2g} / {r['s_onset_ms']:.2g} ms{' (ill)' if j['ill'] else ''}"
              f"{' (onset ill)' if j['onset_ill'] else ''} | {r['op_seconds']:.2f} | {verdict} |", file=out,
              flush=True)
    return rows, summarise(rows)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=32)
    ap.add_argument("--seed", type=int, default=7901)
    ap.add_argument("--seeds", default=None, help="several draws (comma-separated seeds): with --table, a row each")
    ap.add_argument("--seconds", type=float, default=2.0)
    ap.add_argument("--windows", default=None)
    ap.add_argument("--rel", type=float, default=1e-3)
    ap.add_argument("--json", default=None)
    ap.add_argument("--table", action="store_true",
                    help="print only the summary table (a row a draw); the bows' rows go to stderr")
    a = ap.parse_args(argv)
    seeds = [int(x) for x in a.seeds.split(",")] if a.seeds else [a.seed]
    out = sys.stderr if a.table else sys.stdout
    done = []
    for seed in seeds:
        rows, summary = run_draw(a, seed, out)
        done.append((seed, rows, summary))
        if not a.table:
            print(json.dumps(summary, indent=1))
    if a.table:
        print(TABLE_HEAD)
        for seed, _, summary in done:
            print(table_row(seed, summary))
    if a.json:
        with open(a.json, "w") as f:
            json.dump([{"args": vars(a), "seed": seed, "rows": rows, "summary": summary}
                       for seed, rows, summary in done], f, indent=1, default=str)


if __name__ == "__main__":
    main()
