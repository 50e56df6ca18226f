"""Whole processes a user runs, this tree against another source tree (a worktree at an older commit, its compiled
core copied or built in), alternated: `--help`, a 1 s operator note, a 2 s A5 and a 1 s `--method fdm` note.

    PYTHONPATH=. .venv/bin/python benchmarks/process_trees.py OTHER_TREE [--runs 9] [--caches THIS_DIR OTHER_DIR]

As in chorale_trees.py, each process drops the editable install's finder (which would always load this checkout) and
puts its own tree first on sys.path. Each tree has its own cache, empty at the start, or a copy of the one given with
--caches (a user's, full of measurements; each tree's in the layout it reads). Prints Markdown: medians, and each as a
multiple of its tree's `--help`.
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

sys.path.insert(0, str(Path(__file__).resolve().parent))
from chorale_trees import RUNNER, source_tree  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
CASES = {"--help": ["--help"],
         "1 s note, operator": ["render", "--fb", "100", "-d", "1", "a.wav", "--force"],
         "2 s --pitch A5 --fb 553": ["render", "--pitch", "A5", "--fb", "553", "-d", "2", "c.wav", "--force"],
         "1 s note, --method fdm": ["render", "--method", "fdm", "--fb", "100", "-d", "1", "b.wav", "--force"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("other", type=Path)
    ap.add_argument("--runs", type=int, default=9)
    ap.add_argument("--caches", type=Path, nargs=2, metavar=("THIS_DIR", "OTHER_DIR"))
    args = ap.parse_args()
    trees = {"this tree": ROOT, "other tree": source_tree(args.other)}
    # the processes a user runs read their modules' bytecode (see chorale.py)
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONDONTWRITEBYTECODE", "PYTHONPATH")}
    t = {(tr, c): [] for tr in trees for c in CASES}
    with tempfile.TemporaryDirectory() as d:
        for tr, given in zip(trees, args.caches or ()):
            shutil.copytree(given, Path(d) / f"cache-{tr.split()[0]}")
        for i in range(args.runs):
            # the trees take turns going first, as chorale_trees.py's operator processes take turns in each slot
            for tr in list(trees)[::1 if i % 2 == 0 else -1]:
                root = trees[tr]
                for c, argv in CASES.items():
                    t0 = time.perf_counter()
                    # each tree its own cache: one whose measurements have another version (auto windows', say)
                    # would replace the other's table at every turn, and each run would measure afresh (0.4 s)
                    tree_env = {**env, "BOWSYNTH_CACHE": str(Path(d) / f"cache-{tr.split()[0]}")}
                    r = subprocess.run([sys.executable, "-c", RUNNER, str(root), *argv], cwd=d, env=tree_env,
                                       capture_output=True, text=True)
                    t[(tr, c)].append(time.perf_counter() - t0)
                    if r.returncode != 0:
                        raise SystemExit(f"{tr}: bowsynth {' '.join(argv)} failed: {r.stderr.strip()}")
    print(f"medians of {args.runs} alternated runs\n")
    print("| tree | " + " | ".join(CASES) + " |\n|---|" + "---|" * len(CASES))
    for tr in trees:
        h = statistics.median(t[(tr, "--help")])
        cells = [f"{h:.3f} s"] + [f"{statistics.median(t[(tr, c)]):.3f} s, {statistics.median(t[(tr, c)]) / h:.2f}x"
                                  for c in list(CASES)[1:]]
        print(f"| {tr} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
