"""The shipped pitch map against the reference's ratio solve at random bows off its grid, as a Markdown table.

    PYTHONPATH=. .venv/bin/python benchmarks/pitch_map.py [--n 120] [--seed 0]

Bows uniform in log F_B / w over 0.02-2 and in v_B from just above vb_stop to 0.28 (`music.ratio_map.check`): the
cents between the map's sounding ratio and the solver's, and the bows where the two disagree on whether the note
speaks.
"""

from __future__ import annotations

import argparse
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from bowsynth.music.ratio_map import check  # noqa: E402


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=120)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    r = check(a.n, a.seed)
    cents, beta, vb = r["worst"]
    print("| bows off the grid | sounding | median | 90th percentile | worst | disagree on whether the note speaks |")
    print("|---|---|---|---|---|---|")
    print(f"| {r['n']} (seed {a.seed}) | {r['sounding']} | {r['median_cents']:.4f} cents | {r['p90_cents']:.4f} cents | "
          f"{abs(cents):.1f} cents at F_B / w {beta:.3f}, v_B {vb:.4f} | {len(r['disagree'])} |")


if __name__ == "__main__":
    main()
