"""Models trained for one piece (`train --score examples/crescendo.toml`, from scratch or `--from soft-range`) against
the FDM x100 (docs/BENCHMARKS.md, "A box only as wide as a piece" and "Refining the range model for a piece").

    PYTHONPATH=. .venv/bin/python benchmarks/piece_models.py MODEL.safetensors [...] [--json out.json]

For each model, at f0 100 (the training pitch) and 200 (F_B doubled: the same F_B / w): the piece's crescendo (5 s)
against the FDM of the controls the operator applied and of the curve (benchmarks/ranges.py's `gesture`), and held
bows F_B / w 0.09, 0.15, 0.22, 0.30 at v_B 0.15, 1 s from rest: NMSE(p) and the pitch error in cents.
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from ranges import REF, gesture  # noqa: E402

from bowsynth import Scene  # noqa: E402
from bowsynth.metrics import cents, f0_estimate, nmse  # noqa: E402
from bowsynth.engines.fdm import render_fdm  # noqa: E402
from bowsynth.engines.operator.engine import render_operator  # noqa: E402
from bowsynth.engines.operator.modelfile import load_model  # noqa: E402

HELD = (0.09, 0.15, 0.22, 0.30)


def score(path: str) -> dict:
    m = load_model(path)
    rows = {}
    for f0 in (100.0, 200.0):
        k = f0 / 100.0
        rows[f"crescendo f0 {f0:g}"] = gesture(m, "crescendo", [[0, 50.0 * k], [5, 200.0 * k]], 0.15, f0=f0,
                                               seconds=5.0)
        for beta in HELD:
            sc = Scene(f0=f0, fb=beta * 2 * math.pi * f0, vb=0.15, duration=1.0)
            r = render_operator(sc, model=m, fallback="fdm")
            ref = render_fdm(sc, oversample=REF)
            rows[f"F_B / w {beta} f0 {f0:g}"] = {
                "nmse": float(nmse(r.p, ref.p)), "method": r.method,
                "cents": float(cents(f0_estimate(r.p, sc.sample_rate), f0_estimate(ref.p, sc.sample_rate)))}
    return rows


def main(argv):
    out_json = argv[argv.index("--json") + 1] if "--json" in argv else None
    result = {}
    for path in [a for a in argv if a.endswith(".safetensors")]:
        result[path] = rows = score(path)
        print(f"\n## {path}")
        for name, r in rows.items():
            print(f"{name}: " + ", ".join(f"{k} {v:.3g}" if isinstance(v, float) else f"{k} {v}"
                                           for k, v in r.items()))
    if out_json:
        Path(out_json).write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    main(sys.argv[1:])
