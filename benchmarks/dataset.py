"""bowsynth dataset's whole process, one process against Ray workers on this machine: notes per second, and Ray's
cost per task (a batch of BATCH notes) from the two walls.

    .venv/bin/python benchmarks/dataset.py --count 2000 --workers 2

Each run renders the same spec (two-second notes, a quarter of them gestures) into a fresh directory with an empty
cache, as a new user's first corpus; the spec and the machine's load are printed with the numbers.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bowsynth.corpus.build import BATCH  # noqa: E402


def run(spec: Path, out: Path, workers: int, cache: Path) -> float:
    env = dict(os.environ, BOWSYNTH_CACHE=str(cache))
    t0 = time.monotonic()
    p = subprocess.run([sys.executable, "-m", "bowsynth", "dataset", str(spec), "--out", str(out), "--workers",
                        str(workers)], capture_output=True, text=True, env=env)
    if p.returncode != 0:
        raise SystemExit(p.stderr)
    return time.monotonic() - t0


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--count", type=int, default=2000)
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="bowsynth-dataset-bench-"))
    spec = tmp / "spec.toml"
    spec.write_text(f"count = {args.count}\nseed = 11\nduration = 2.0\ngestures = 0.25\n")
    print(f"spec: {spec.read_text().strip().replace(chr(10), '; ')}; load before: {os.getloadavg()[0]:.2f}")
    print()
    one = run(spec, tmp / "one", 1, tmp / "cache-one")
    many = run(spec, tmp / "many", args.workers, tmp / "cache-many")
    tasks = -(-args.count // BATCH)
    per_task = one / tasks
    overhead = (many - one / args.workers) / tasks * args.workers  # each task's share of what the parallel run lost
    print(f"| workers | wall s | notes / s |\n|---|---|---|\n| 1 (one process) | {one:.1f} | {args.count / one:.1f} |\n"
          f"| {args.workers} (Ray) | {many:.1f} | {args.count / many:.1f} |")
    print(f"\nspeed-up {one / many:.2f}x; a task ({BATCH} notes) {per_task:.2f} s in one process; Ray's cost per task "
          f"{overhead:.3f} s ({100 * overhead / per_task:.1f} % of a task, Ray's start-up included)")


if __name__ == "__main__":
    main()
