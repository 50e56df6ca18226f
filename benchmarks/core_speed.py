"""The compiled core's speed: whole processes alternated with `bowsynth --help`, and the rollout in
multiples of real time, beside this machine's float32 matrix-product speed measured in the same run (the CPU is shared:
the ratio to it says what the loops reach of what the machine gave at that moment).

    PYTHONPATH=. .venv/bin/python benchmarks/core_speed.py [--runs 5]

Prints Markdown (docs/BENCHMARKS.md, "Compiled core").
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # this tree, not an installed bowsynth
# the processes a user runs read their modules' bytecode: a shell that sets PYTHONDONTWRITEBYTECODE (this machine's
# does) would have every process compile the edited modules again (~0.1 s of a chorale's process)
ENV = {**{k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}, "PYTHONPATH": str(ROOT)}

CASES = {"--help": ["--help"],
         "1 s note, operator": ["render", "--fb", "100", "-d", "1", "a.wav"],
         "1 s note, --method fdm": ["render", "--method", "fdm", "--fb", "100", "-d", "1", "b.wav"],
         "2 s --pitch A5 --fb 553": ["render", "--pitch", "A5", "--fb", "553", "-d", "2", "c.wav"]}


def whole_processes(runs: int) -> None:
    times = {k: [] for k in CASES}
    with tempfile.TemporaryDirectory() as d:
        for _ in range(runs):  # alternated: a change in the machine's load hits every case
            for name, args in CASES.items():
                t0 = time.perf_counter()
                subprocess.run([sys.executable, "-m", "bowsynth", *args], cwd=d, env=ENV, capture_output=True,
                               check=True)
                times[name].append(time.perf_counter() - t0)
    base = statistics.median(times["--help"])
    print("| process | median s | x `--help` |\n|---|---|---|")
    for name, ts in times.items():
        print(f"| {name} | {statistics.median(ts):.3f} | {statistics.median(ts) / base:.2f} |")


def best_cpu(f, n, clock=time.process_time):
    """The shortest of n runs of f by clock (CPU time by default: what one thread costs, whatever else runs)."""
    ts = []
    for _ in range(n):
        t0 = clock()
        f()
        ts.append(clock() - t0)
    return min(ts)


def rollouts() -> None:
    import numpy as np

    from bowsynth.engines.operator.choose import SHIPPED_DIR
    from bowsynth.engines.operator.modelfile import load_model
    from bowsynth.engines.operator.rollout import rollout_states, threads

    a = np.random.rand(512, 512).astype(np.float32)
    gmac = 512**3 / best_cpu(lambda: a @ a, 20) / 1e9
    m = load_model(SHIPPED_DIR / "paper-fb100.safetensors")
    k = m.cfg.k
    print(f"\nfloat32 matrix product (numpy's BLAS, one thread) in this run: {gmac:.1f} GMAC/s\n")
    print("| rollout (paper-fb100, CPU time, best of 5) | x real time | GMAC/s | of the BLAS speed |\n|---|---|---|---|")
    mac_window = 32_800  # the branch per window (docs/measures.md); per sample the window's basis: 2 (k + 3)
    for f0 in (100.0, 440.0, 880.0):
        dt = 2 * np.pi * f0 / 44100
        rollout_states(m, [[0.0, 0.0]], 100, dt, check_domain=False)
        x = 5 / best_cpu(lambda: rollout_states(m, [[0.0, 0.0]], 5 * 44100, dt, check_domain=False), 5)
        g = x * (mac_window * f0 + 2 * (k + 3) * 44100) / 1e9
        print(f"| one voice, {f0:g} Hz | {x:.0f}x | {g:.1f} | {g / gmac:.0%} |")
    f0 = 100 * 2 ** np.random.default_rng(0).uniform(0, 3, 64)
    dt = 2 * np.pi * f0 / 44100
    rollout_states(m, np.zeros((64, 2)), 100, dt, check_domain=False)
    for loop, what in (("core-voices", "voice after voice"), ("core-1", "in groups by pitch")):
        x = 64 * 2 / best_cpu(lambda: rollout_states(m, np.zeros((64, 2)), 2 * 44100, dt, check_domain=False,
                                                     loop=loop), 3)
        g = x * (mac_window * f0.mean() + 2 * (k + 3) * 44100) / 1e9
        print(f"| 64 voices, 100-800 Hz, aggregate, one thread, {what} | {x:.0f}x | {g:.1f} | {g / gmac:.0%} |")
    # what a render does: the voices split over the process's cores; wall clock, so the cores add up
    x = 64 * 2 / best_cpu(lambda: rollout_states(m, np.zeros((64, 2)), 2 * 44100, dt, check_domain=False), 5,
                          time.perf_counter)
    g = x * (mac_window * f0.mean() + 2 * (k + 3) * 44100) / 1e9
    print(f"| 64 voices, 100-800 Hz, aggregate, {threads()} threads (wall clock) | {x:.0f}x | {g:.1f} | "
          f"{g / gmac:.0%} of one core |")


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=5)
    args = ap.parse_args()
    print(f"load average at start: {os.getloadavg()[0]:.2f}\n")
    whole_processes(args.runs)
    rollouts()
