"""Where a chorale's `score --mix` process spends its time, per engine: the imports, the score's notes (each pitch
tuned for the engine), the render and the mix written, each timed inside a fresh process, the two engines
alternated (against the 0.5x target: what the operator's render may cost once the costs both processes share are paid).

    PYTHONPATH=. .venv/bin/python benchmarks/chorale_phases.py [--runs 3]

The piece is benchmarks/chorale.py's. The interpreter's own start is `bowsynth --help`'s (benchmarks/chorale.py).
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import chorale as C  # noqa: E402

PHASES = r"""
import json, sys, time
t0 = time.perf_counter()
from pathlib import Path
from bowsynth.engines.operator.choose import available_models
from bowsynth.music import perform
from bowsynth.music.engine_tuning import ratio_for_engine
from bowsynth.music.mix import write_voices
from bowsynth.music.score import load_score
t1 = time.perf_counter()
method, piece, out = sys.argv[1:4]
pool = available_models() if method == "operator" else None
notes = load_score(piece, ratio_for=lambda sc: ratio_for_engine(sc, method, None, models=pool, windows="locked")[0])
t2 = time.perf_counter()
rs = perform.render_notes(notes, method=method)
t3 = time.perf_counter()
write_voices(notes, rs, Path(out), mix=True, force=True)
t4 = time.perf_counter()
print(json.dumps({"imports": t1 - t0, "score": t2 - t1, "render": t3 - t2, "write": t4 - t3}))
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3)
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        piece = Path(d) / "chorale.mid"
        C.write_piece(piece)
        got: dict = {"operator": [], "fdm": []}
        for _ in range(a.runs):
            for method in got:
                p = subprocess.run([sys.executable, "-c", PHASES, method, str(piece), str(Path(d) / f"{method}.wav")],
                                   capture_output=True, text=True, env=C.ENV, check=True)
                got[method].append(json.loads(p.stdout.strip().splitlines()[-1]))
    print(f"medians of {a.runs} runs (s), each phase timed inside its process\n")
    print("| engine | imports | score's notes | render | mix written | sum |\n|---|---|---|---|---|---|")
    for method, rows in got.items():
        med = {k: statistics.median(r[k] for r in rows) for k in rows[0]}
        print(f"| {method} | " + " | ".join(f"{med[k]:.3f}" for k in med) + f" | {sum(med.values()):.3f} |")


if __name__ == "__main__":
    main()
