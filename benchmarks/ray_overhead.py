"""Ray's cost per task, apart from its start-up: the dataset's own tasks (a batch of BATCH two-second notes) on a
local cluster, each timed inside its worker, against the driver's wall once the workers are warm.

    .venv/bin/python benchmarks/ray_overhead.py --tasks 40 --workers 2

Printed: the cluster's start-up (ray.init and the workers' first import of bowsynth, a warm-up task each), the work
inside the tasks, the wall, and Ray's cost per task: (wall x workers - the tasks' own time) / tasks, the time a
worker was not running a task's work (scheduling, pickling the job and its rows, the driver's wait); also the same
for empty tasks (what a task costs that does nothing). The issue's bound: under 5 % of a task.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bowsynth.corpus.build import BATCH, _claim, _render_batch, plan  # noqa: E402
from bowsynth.corpus.spec import read_spec  # noqa: E402
from bowsynth.io.cluster import Pool  # noqa: E402


def timed_batch(job):
    """A dataset task timed inside its worker: (seconds of work, rows)."""
    t = time.perf_counter()
    rows = _render_batch(job)
    return time.perf_counter() - t, len(rows)


def empty(_):
    return 0.0, 0


def run(pool: Pool, fn, jobs) -> tuple[float, float]:
    """(wall, the tasks' own time summed)."""
    t = time.perf_counter()
    inside = sum(r[0] for _, r in pool.map(fn, jobs))
    return time.perf_counter() - t, inside


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--tasks", type=int, default=40)
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="bowsynth-ray-overhead-"))
    os.environ["BOWSYNTH_CACHE"] = str(tmp / "cache")
    spec_file = tmp / "spec.toml"
    spec_file.write_text(f"count = {BATCH * (args.tasks + args.workers)}\nseed = 11\nduration = 2.0\n"
                         "gestures = 0.25\n")
    spec = read_spec(spec_file)
    notes = plan(spec)
    out = tmp / "corpus"
    _claim(out, spec)  # the corpus's directory as `dataset` makes it
    jobs = [(notes[a:a + BATCH], spec, False, str(out)) for a in range(0, len(notes), BATCH)]
    warm, work = jobs[:args.workers], jobs[args.workers:]
    print(f"load before: {os.getloadavg()[0]:.2f}; {args.workers} workers, {len(work)} tasks of {BATCH} notes")
    t = time.perf_counter()
    pool = Pool(args.workers)
    run(pool, timed_batch, warm)  # each worker imports bowsynth and reads its models once
    start = time.perf_counter() - t
    wall, inside = run(pool, timed_batch, work)
    e_wall, _ = run(pool, empty, range(200))
    pool.close()
    per_task = inside / len(work)
    cost = (wall * args.workers - inside) / len(work)
    print(f"start-up (ray.init and one warm-up task a worker) {start:.2f} s")
    print(f"dataset tasks: wall {wall:.2f} s, work inside the tasks {inside:.2f} s ({per_task:.3f} s a task); Ray's "
          f"cost per task {cost * 1000:.1f} ms = {100 * cost / per_task:.2f} % of a task")
    print(f"empty tasks: {e_wall / 200 * args.workers * 1000:.2f} ms each (200, wall x workers / tasks)")


if __name__ == "__main__":
    main()
