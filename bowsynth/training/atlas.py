"""An atlas's units (training recipes) trained as independent tasks: each after the unit whose model it refines, in
waves, on Ray (io.cluster.Pool) or in this process; a unit whose worker dies runs again and continues from its
checkpoint (`train --update`), so it loses at most one checkpoint interval.

    bowsynth train --atlas models --workers 2        # every recipe there and in stages/
    python -m bowsynth.training.atlas schedule models # units, their budgets, the wall on 1 / 8 / 64 workers
"""

from __future__ import annotations

import ctypes
import signal
import subprocess
import sys
import time
from pathlib import Path

from ..errors import UsageError
from .recipe import build_order, load_recipe, parents

PR_SET_PDEATHSIG = 1


def atlas_recipes(spec) -> list[Path]:
    """The units of an atlas: a directory's recipes (*.toml there and in its stages/), or the recipe files given."""
    specs = [Path(s) for s in (spec if isinstance(spec, (list, tuple)) else [spec])]
    out: list[Path] = []
    for s in specs:
        if s.is_dir():
            out += sorted(s.glob("stages/*.toml")) + sorted(s.glob("*.toml"))
        elif s.is_file():
            out.append(s)
        else:
            raise UsageError(f"--atlas {s}: no such directory or recipe file")
    if not out:
        raise UsageError(f"--atlas {', '.join(map(str, specs))}: no recipes (*.toml) there")
    return out


def waves(paths) -> list[list[Path]]:
    """The recipes in waves: every unit after the wave of the unit it refines (a cycle is refused by build_order)."""
    order = build_order(paths)
    up = parents(order)
    level: dict[Path, int] = {}
    for p in order:
        level[p] = 0 if up[p] is None else level[up[p]] + 1
    return [[p for p in order if level[p] == k] for k in range(max(level.values()) + 1)]


def _die_with_parent() -> None:
    """In the child: die when the worker that started it dies (a killed Ray worker leaves no training behind to hold
    the model's lock against the retry)."""
    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    except (OSError, AttributeError):
        pass


def _unit(recipe: str) -> dict:
    """A task: `bowsynth train --config RECIPE --update` in a child process; its outcome."""
    t0 = time.monotonic()
    p = subprocess.run([sys.executable, "-m", "bowsynth", "train", "--config", recipe, "--update"],
                       capture_output=True, text=True, preexec_fn=_die_with_parent)
    lines = [ln for ln in (p.stdout + p.stderr).splitlines() if ln.strip()]
    return {"recipe": recipe, "rc": p.returncode, "seconds": time.monotonic() - t0, "said": lines[-1] if lines else ""}


def eta_seconds(done: list[dict], left_minutes: list[float], workers: int) -> float | None:
    """The wall still to wait, in seconds: the units left's budgets (their recipes' `minutes`), at the pace the units
    done kept against theirs (a unit up to date takes seconds of its budget), spread over the workers (no fewer
    rounds than the longest unit left); None before a unit with a budget has finished."""
    if not left_minutes:
        return 0.0
    spent = sum(r["seconds"] for r in done if r.get("minutes"))
    budget = sum(60.0 * r["minutes"] for r in done if r.get("minutes"))
    if not budget:
        return None
    pace = spent / budget
    return pace * 60.0 * max(sum(left_minutes) / max(1, min(workers, len(left_minutes))), max(left_minutes))


def run_atlas(paths, workers: int = 1, address: str | None = None, progress=None) -> list[dict]:
    """Train the units wave by wave; progress(done, total, running, eta) after each (eta: eta_seconds, or None). A
    failed unit's refinements are not started (reported as skipped)."""
    from ..io.cluster import Pool

    ws = waves(paths)
    up = parents([p for w in ws for p in w])
    total = sum(len(w) for w in ws)
    minutes = {p: float(load_recipe(p).get("minutes", 5.0)) for w in ws for p in w}
    results: dict[Path, dict] = {}
    with Pool(workers, address) as pool:
        for wave in ws:
            run = [p for p in wave if up[p] is None or results.get(up[p], {}).get("rc") == 0]
            for p in wave:
                if p not in run:
                    results[p] = {"recipe": str(p), "rc": None, "seconds": 0.0,
                                  "said": f"skipped: {up[p]} did not train"}
            for i, res in pool.map(_unit, [str(p) for p in run]):
                results[run[i]] = dict(res, minutes=minutes[run[i]])
                if progress is not None:
                    left = [minutes[p] for w in ws for p in w if p not in results]
                    progress(len(results), total, min(workers, len(run) - sum(1 for p in run if p in results)),
                             eta_seconds(list(results.values()), left, workers))
        note = pool.note
    out = [results[p] for w in ws for p in w]
    if note:
        out.append({"note": note})
    return out


def schedule(paths, workers=(1, 8, 64), overhead: float = 0.0) -> list[tuple[int, float]]:
    """The wall (minutes) of training the units on each number of workers: list scheduling of each wave's units by
    their recipes' `minutes` (longest first), waves one after another, plus `overhead` minutes a task."""
    import heapq

    ws = waves(paths)
    out = []
    for n in workers:
        wall = 0.0
        for wave in ws:
            times = sorted((float(load_recipe(p).get("minutes", 5.0)) + overhead for p in wave), reverse=True)
            free = [0.0] * min(n, len(times))
            for t in times:
                heapq.heappush(free, heapq.heappop(free) + t)
            wall += max(free)
        out.append((n, wall))
    return out


if __name__ == "__main__":
    if sys.argv[1:2] != ["schedule"] or len(sys.argv) < 3:
        sys.exit("usage: python -m bowsynth.training.atlas schedule DIR|RECIPE ...")
    units = atlas_recipes(sys.argv[2:])
    ws = waves(units)
    budget = sum(float(load_recipe(p).get("minutes", 5.0)) for p in units)
    print(f"{len(units)} units in {len(ws)} waves ({', '.join(str(len(w)) for w in ws)}), {budget:.0f} minutes of "
          f"training in all")
    for n, wall in schedule(units):
        print(f"{n:>3} workers: {wall:7.0f} minutes ({wall / 60:.1f} h)")
