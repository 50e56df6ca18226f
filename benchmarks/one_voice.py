"""One voice's rollout in multiples of real time (>= 1000x at f0 <= 150 Hz, >= 300x at 880 Hz), for the
soft range models (width 128) and `paper-fb100` (width 64), with the branch's weights in panels and strided
(BOWSYNTH_NO_PANELS=1: the same samples), alternated in fresh processes round by round.

    PYTHONPATH=. .venv/bin/python benchmarks/one_voice.py [--rounds 3] [--f0 880,440,100]

Each figure: 5 s from rest at one bow of the model's box, CPU time, the best of 15 (numpy's BLAS held to one
thread). Prints Markdown (docs/BENCHMARKS.md, "Weights in panels").
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

MODELS = (("soft-range", (0.15, 0.2)), ("soft-high", (0.3, 0.2)), ("velocity-soft", (0.2, 0.15)),
          ("paper-fb100", None))
CHILD = """
import json, math, sys, time
import numpy as np
from bowsynth.engines.operator.choose import SHIPPED_DIR
from bowsynth.engines.operator.modelfile import load_model
from bowsynth.engines.operator.rollout import rollout_states
out = {}
for name, bow in json.loads(sys.argv[1]):
    m = load_model(SHIPPED_DIR / f"{name}.safetensors")
    kw = {} if bow is None else {"params": np.array(bow)}
    for f0 in json.loads(sys.argv[2]):
        dt = 2 * math.pi * f0 / 44100
        rollout_states(m, [[0.0, 0.0]], 100, dt, check_domain=False, **kw)
        best = 1e9
        for _ in range(15):
            t0 = time.process_time()
            rollout_states(m, [[0.0, 0.0]], 5 * 44100, dt, check_domain=False, **kw)
            best = min(best, time.process_time() - t0)
        out[f"{name} {f0:g}"] = 5 / best
print(json.dumps(out))
"""


def run(panels: bool, f0s: list[float]) -> dict:
    env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "BOWSYNTH_NO_PANELS": "0" if panels else "1"}
    r = subprocess.run([sys.executable, "-c", CHILD, json.dumps(MODELS), json.dumps(f0s)], env=env,
                       capture_output=True, text=True, check=True)
    return json.loads(r.stdout)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--f0", default="880,440,100")
    a = ap.parse_args()
    f0s = [float(x) for x in a.f0.split(",")]
    rounds = [(run(False, f0s), run(True, f0s)) for _ in range(a.rounds)]
    print("| model, f0 | strided (x real time, each round) | panels |\n|---|---|---|")
    for key in rounds[0][0]:
        print(f"| {key} Hz | {' / '.join(f'{s[key]:.0f}' for s, _ in rounds)} | "
              f"{' / '.join(f'{p[key]:.0f}' for _, p in rounds)} |")


if __name__ == "__main__":
    main()
