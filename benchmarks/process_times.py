"""What the user waits for: whole processes of the installed `bowsynth`, each A run alternated with its B (A B A B
...), the medians and the median of the ratios pair by pair; a cold A gets an empty cache of its own each run.

    .venv/bin/python benchmarks/process_times.py [--runs 7]

Printed: the Markdown table docs/BENCHMARKS.md shows, against the targets (a cold render of a new bow within 1.6x
`bowsynth --help`, any bow, `--pitch` included; a 5 s note's whole process at most 0.8x the FDM's). Bytecode is
written as an install has it (a shell that sets PYTHONDONTWRITEBYTECODE would have each process compile bowsynth's
modules again).
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

BIN = Path(sys.executable).parent
BOW = str(BIN / "bowsynth")
PY = sys.executable
NOTE = ["--f0", "220", "--fb", "600", "--vb", "0.17"]


def timed(cmd: list[str], env: dict, cwd: str) -> float:
    t = time.perf_counter()
    p = subprocess.run(cmd, env=env, cwd=cwd, capture_output=True)
    wall = time.perf_counter() - t
    if p.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed: {p.stderr.decode(errors='replace').strip()[-300:]}")
    return wall


def pair(a: list[str], b: list[str], runs: int, cold: bool, cwd: str, base: dict) -> tuple[float, float, float]:
    """(median A, median B, median of A / B pair by pair); one untimed run of each first."""
    ta, tb = [], []
    for i in range(runs + 1):
        env = dict(base)
        if cold:
            env["BOWSYNTH_CACHE"] = tempfile.mkdtemp(prefix="cold-", dir=cwd)
        x, y = timed(a, env, cwd), timed(b, base, cwd)
        if cold:
            shutil.rmtree(env["BOWSYNTH_CACHE"], ignore_errors=True)
        if i:
            ta.append(x)
            tb.append(y)
    return statistics.median(ta), statistics.median(tb), statistics.median(x / y for x, y in zip(ta, tb))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=7)
    a = ap.parse_args(argv)
    cwd = tempfile.mkdtemp(prefix="process-times-")  # no ./models there
    base = {k: v for k, v in os.environ.items() if k not in ("PYTHONDONTWRITEBYTECODE", "BOWSYNTH_CACHE")}
    base["BOWSYNTH_CACHE"] = str(Path(cwd) / "warm-cache")
    help_ = [BOW, "--help"]
    rows = [
        ("`bowsynth render --f0 220 --fb 600 --vb 0.17 -d 2 -q cold.wav` (a new bow, soft)",
         [BOW, "render", *NOTE, "-d", "2", "-q", "cold.wav"], help_, True, "`bowsynth --help`", 1.6),
        ("`bowsynth render --pitch A4 --fb 300 -d 2 -q a4.wav` (a new note by name)",
         [BOW, "render", "--pitch", "A4", "--fb", "300", "-d", "2", "-q", "a4.wav"], help_, True, "`--help`", 1.6),
        ("the same note as the first, 5 s, warm", [BOW, "render", *NOTE, "-d", "5", "-q", "warm.wav"],
         [BOW, "render", "--method", "fdm", *NOTE, "-d", "5", "-q", "fdm.wav"], False, "`--method fdm`", 0.8),
        ("`python -c \"import numpy, soundfile\"` (what any render imports)", [PY, "-c", "import numpy, soundfile"],
         help_, False, "`--help`", None),
    ]
    timed(rows[2][1], base, cwd)  # the warm note's measurements, once
    print(f"{a.runs} alternated runs each after one untimed, medians; the machine's load "
          f"{os.getloadavg()[0]:.2f} at the start\n")
    print("| command (A) | A | B | A / B | target |\n|---|---|---|---|---|")
    for label, cmd_a, cmd_b, cold, b_label, target in rows:
        ma, mb, ratio = pair(cmd_a, cmd_b, a.runs, cold, cwd, base)
        verdict = "" if target is None else f"{target:g}x: {'met' if ratio <= target else '**missed**'}"
        print(f"| {label} | {ma:.3f} s | {b_label} {mb:.3f} s | {ratio:.2f}x | {verdict} |", flush=True)
    shutil.rmtree(cwd, ignore_errors=True)


if __name__ == "__main__":
    main()
