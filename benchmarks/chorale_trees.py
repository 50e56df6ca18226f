"""The chorale's whole processes (`score --mix`, as `benchmarks/chorale.py` writes the piece) of another source tree
(a worktree at an older commit, its compiled core copied or built in) against this one, alternated, with `--help`
and the FDM beside them, and each operator mix's distance from the FDM's.

    PYTHONPATH=. .venv/bin/python benchmarks/chorale_trees.py OTHER_TREE [--runs 7] [--windows locked,physics]

Why a runner of its own: with an editable install (scikit-build-core's), PYTHONPATH does not choose the tree a
process imports: the install's finder comes first on sys.meta_path and always loads this checkout. Each process here
drops that finder and puts its tree first on sys.path.
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

sys.path.insert(0, str(Path(__file__).resolve().parent))
import chorale as C  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
RUNNER = ("import sys\n"
          "sys.meta_path = [f for f in sys.meta_path if type(f).__name__ != 'ScikitBuildRedirectingFinder']\n"
          "sys.path.insert(0, sys.argv.pop(1))\n"
          "from bowsynth.cli.main import main\n"
          "sys.argv[0] = 'bowsynth'\n"
          "sys.exit(main())\n")


def source_tree(path: Path) -> Path:
    """OTHER_TREE resolved, or the run refused: a path with no bowsynth package would have RUNNER's processes import
    this checkout (through the venv), measuring this tree twice."""
    if not (path / "bowsynth" / "__init__.py").is_file():
        raise SystemExit(f"{path} holds no bowsynth package")
    return path.resolve()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("other", type=Path)
    ap.add_argument("--runs", type=int, default=7)
    ap.add_argument("--windows", default="locked", help="this tree's operator windows, comma-separated")
    a = ap.parse_args()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONDONTWRITEBYTECODE", "PYTHONPATH")}
    score = ["score", "--score", "chorale.mid", "--mix", "--force"]
    procs = {"help": (ROOT, ["--help"]), "other locked": (source_tree(a.other), [*score, "other.wav"])}
    for w in a.windows.split(","):
        procs[f"this {w}"] = (ROOT, [*score, f"this-{w}.wav", "--windows", w])
    procs["fdm"] = (ROOT, [*score, "fdm.wav", "--method", "fdm"])
    with tempfile.TemporaryDirectory() as d:
        C.write_piece(Path(d) / "chorale.mid")
        times = {k: [] for k in procs}
        ops = [k for k in procs if k not in ("help", "fdm")]
        for i in range(a.runs + 1):  # the first round warms the caches and is not counted
            # the operator processes take turns in each slot: the one right after another operator process ran
            # 0.08-0.1 s slower whichever tree it was
            order = ["help", *ops[i % len(ops):], *ops[:i % len(ops)], "fdm"]
            for k in order:
                tree, args = procs[k]
                t0 = time.perf_counter()
                cache = str(Path(d) / ("cache" + str(tree).replace("/", "_")))  # each tree its own (process_trees.py)
                r = subprocess.run([sys.executable, "-c", RUNNER, str(tree), *args], cwd=d,
                                   env={**env, "BOWSYNTH_CACHE": cache}, capture_output=True, text=True)
                if r.returncode != 0:
                    raise SystemExit(f"{k} failed: {r.stderr.strip()}")
                if i:
                    times[k].append(time.perf_counter() - t0)
        med = {k: statistics.median(v) for k, v in times.items()}
        print(f"medians of {a.runs} alternated runs (s)\n")
        print("| process | seconds | x --help | x the FDM's |\n|---|---|---|---|")
        for k in procs:
            print(f"| {k} | {med[k]:.3f} | {med[k] / med['help']:.2f} | {med[k] / med['fdm']:.2f} |")
        fdm = C.mix_physical(Path(d) / "fdm.wav")
        for k in [k for k in procs if k not in ("help", "fdm")]:
            name = "other.wav" if k.startswith("other") else f"this-{k.split()[1]}.wav"
            op = C.mix_physical(Path(d) / name)
            lsd = ", ".join(f"{f:.0f} dB floor {C.frame_lsd(op, fdm, 44100, f):.2f} dB" for f in (80.0, 60.0, 40.0))
            print(f"\n{k}: median log-spectral distance from the FDM's mix per 8192-sample frame: {lsd}")


if __name__ == "__main__":
    main()
