"""One cell of `bowsynth bench map` at 110 and 440 Hz, in the windows asked: who plays it, and its errors against the
x100 FDM (cents, harmonics median / worst in dB, onset error in ms), as `analysis.error_map.map_cell` scores them.

    PYTHONPATH=. .venv/bin/python benchmarks/map_cell.py BETA VB [free,locked,physics,auto]
"""

from __future__ import annotations

import sys

from bowsynth.analysis.error_map import map_cell


def main() -> None:
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    beta, vb = float(sys.argv[1]), float(sys.argv[2])
    print("| windows | f0 | status | model | cents | harmonics median / worst (dB) | onset error (ms) |")
    print("|---|---|---|---|---|---|---|")
    for w in (sys.argv[3] if len(sys.argv) > 3 else "free,auto").split(","):
        for f0 in (110.0, 440.0):
            c = map_cell(f0, beta, vb, windows=w)
            o = c.get("op")
            errs = (f"{o['cents']:+.3f} | {o['harm_db_median']:.3f} / {o['harm_db_max']:.3f} | "
                    f"{o['onset_err_ms']:+.2f}") if o else f"{c.get('why', '')} | | "
            print(f"| {w} | {f0:g} | {c['status']} | {c.get('model_name', '')} | {errs} |")


if __name__ == "__main__":
    main()
