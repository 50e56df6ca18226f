"""What auto windows measure at a held bow, truth-free, beside what the truth says of each choice: per random held
bow played by a range model, the operator's own measurements (its free cycle against the shipped map's period, the
median 100 ms frame's wander, the lock's harmonic shift from the free note), the choice, and the x100 FDM's verdict
on free windows and on windows locked to the map's period.

    PYTHONPATH=. .venv/bin/python benchmarks/auto_rule.py [--n 32] [--seed 7912] [--frames]

--frames: the choice for a note heard frame by frame (an attack or a bow stop); by default a held note's. One line a
bow: f0, F_B / w, v_B; own (cents of the free cycle from the map), wander (cents, at f0 100 in frames holding as many
periods as 100 ms at f0), shift (dB); the choice (L lock, F free); free and lock against the truth (worst harmonic
dB, cents; X where over 1 dB or 1 cent). The summary counts the bows where the choice was the worse of the two.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import tempfile
import warnings

sys.path.insert(0, os.path.dirname(__file__))

from truth_free import draw, no_reference, truth_of  # noqa: E402

from bowsynth.api import render  # noqa: E402
from bowsynth.engines.operator.windows import Lock  # noqa: E402
from bowsynth.metrics import cents, listener_errors, note_sounds  # noqa: E402
from bowsynth.music import engine_tuning as ET  # noqa: E402
from bowsynth.music.model_ratio import lock_ratio, own_ratio  # noqa: E402
from bowsynth.music.pick import heard_pick  # noqa: E402


def over(e) -> float:
    """How far a render misses the held note's targets (1 dB, 1 cent): the larger ratio."""
    return max(e[0] / ET.TARGET_DB, abs(e[1]) / ET.TARGET_CENTS)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=32)
    ap.add_argument("--seed", type=int, default=7912)
    ap.add_argument("--seconds", type=float, default=2.0)
    ap.add_argument("--frames", action="store_true")
    a = ap.parse_args(argv)
    os.environ["BOWSYNTH_CACHE"] = tempfile.mkdtemp(prefix="auto-rule-cache-")
    warnings.simplefilter("ignore")
    worse = played = 0
    for f0, beta, vb in draw(a.n, a.seed):
        sc, truth = truth_of(f0, beta, vb, a.seconds)
        if not note_sounds(truth.p):
            continue
        m = heard_pick(sc)
        if m is None or not m.domain.is_range or not isinstance(lock := lock_ratio(m, beta, vb, sc.a), Lock):
            continue  # a point model, or a model that does not hold the map's period here: free windows, no choice
        own = own_ratio(m, beta, vb, sc.a)
        scn, free = ET._held_note(m, beta, vb, sc.a, None)
        frame = round(0.1 * f0 / 100.0, 3)
        wander = ET.frame_wander(free.q, scn.sample_rate, scn.f0 * float(lock), frame) if free is not None else math.inf
        shift = ET.lock_harmonic_shift(m, beta, vb, sc.a, lock, free)
        chose_lock = ET.auto_lock(m, beta, vb, sc.a, f0, a.frames) is not None
        got = {}
        for w in ("free", "physics"):
            with no_reference():
                e = listener_errors(render(sc, engine="operator", model=m, windows=w).p, truth.p, sc.sample_rate)
            got[w] = (e["harm_db_max"], e["cents"])
        played += 1
        mine, other = (got["physics"], got["free"]) if chose_lock else (got["free"], got["physics"])
        worse += over(mine) > 1 >= over(other)
        own_c = f"{cents(own, float(lock)):+7.3f}" if own else "   none"
        flag = {k: "X" if over(v) > 1 else " " for k, v in got.items()}
        print(f"{f0:6.1f} {beta:.3f} {vb:.4f} own {own_c} wander {wander:6.3f} shift {shift:5.2f} "
              f"{'L' if chose_lock else 'F'} | free {got['free'][0]:5.2f} dB {got['free'][1]:+6.3f} c{flag['free']} "
              f"| lock {got['physics'][0]:5.2f} dB {got['physics'][1]:+6.3f} c{flag['physics']}", flush=True)
    print(f"{played} held bows with a choice (seed {a.seed}, {'frames' if a.frames else 'held'}): the choice missed "
          f"a target the other met at {worse}")


if __name__ == "__main__":
    main()
