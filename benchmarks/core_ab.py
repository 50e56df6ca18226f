"""Two builds of the compiled core against each other, in one process, called alternately (a machine whose speed
drifts hits both alike): the rollout of one voice at 100 / 440 / 880 Hz and of 64 voices at 100-800 Hz, one thread,
best CPU time of each over the rounds.

    git worktree add /tmp/old HEAD~1 && cmake -S /tmp/old -B /tmp/old/build -G Ninja -DCMAKE_BUILD_TYPE=Release \\
        -DPython_EXECUTABLE=$PWD/.venv/bin/python && cmake --build /tmp/old/build
    mkdir -p /tmp/a/old && cp /tmp/old/build/_core*.so /tmp/a/old/      # a package directory per build
    PYTHONPATH=. .venv/bin/python benchmarks/core_ab.py paper-fb100 /tmp/a:old [--rounds 7]

The first build is this tree's own (bowsynth._core); each DIR:NAME adds DIR/NAME/_core*.so, imported as NAME._core.
Only the kernels are swapped: the Python around them is this tree's, so the builds must share its ABI.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bowsynth import compiled  # noqa: E402
from bowsynth.engines.operator.choose import as_model  # noqa: E402
from bowsynth.engines.operator import rollout  # noqa: E402


def loop_args(model, x0, n, dtau) -> tuple:
    """The arguments rollout_states hands its compiled loop (outputs included), so the loops can be timed alone:
    allocating a render's outputs costs page faults that vary from call to call more than the builds differ."""
    got = []
    real = rollout._roll_groups
    rollout._roll_groups = lambda args, n_threads: got.append(args)
    try:
        rollout.rollout_states(model, x0, n, dtau, check_domain=False, loop="core-1")
    finally:
        rollout._roll_groups = real
    return got[0]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("model", help="a model file or a shipped model's name")
    ap.add_argument("builds", nargs="+", metavar="DIR:NAME")
    ap.add_argument("--rounds", type=int, default=7)
    a = ap.parse_args(argv)
    m = as_model(a.model)
    mods = {"this tree": compiled.load()}
    for spec in a.builds:
        d, name = spec.rsplit(":", 1)
        sys.path.insert(0, d)
        mods[spec] = importlib.import_module(f"{name}._core")
    f064 = 100 * 2 ** np.random.default_rng(0).uniform(0, 3, 64)
    cases = {f"one voice, {f0:g} Hz": (np.zeros((1, 2)), 2 * np.pi * f0 / 44100, 3 * 44100) for f0 in (100, 440, 880)}
    cases["64 voices, 100-800 Hz"] = (np.zeros((64, 2)), 2 * np.pi * f064 / 44100, 44100)
    args = {c: loop_args(m, x0, n, dt) for c, (x0, dt, n) in cases.items()}
    best = {(c, b): 0.0 for c in cases for b in mods}
    for _ in range(a.rounds):
        for c, (x0, dt, n) in cases.items():
            for b, mod in mods.items():
                compiled._module = mod
                t = time.process_time()
                rollout._roll_groups(args[c], 1)
                best[(c, b)] = max(best[(c, b)], len(x0) * n / 44100 / (time.process_time() - t))
    compiled._module = None
    print(f"| rollout ({a.model}, one thread, x real time) | " + " | ".join(mods) + " |")
    print("|---|" + "---|" * len(mods))
    for c in cases:
        base = best[(c, "this tree")]
        print(f"| {c} | " + " | ".join(f"{best[(c, b)]:.0f}x ({best[(c, b)] / base:.2f})" for b in mods) + " |")


if __name__ == "__main__":
    main()
