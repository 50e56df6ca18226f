"""A long piece as a user renders it: 8 voices of 60 s each, one held note per voice at 8 pitches of a
chord, F_B / w of the shipped paper-fb100 model, `bowsynth score --mix`, operator against `--method fdm`, whole
process, alternated.

    PYTHONPATH=. .venv/bin/python benchmarks/long_score.py [--runs 3] [--seconds 60]
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from cli_speed import alternate  # noqa: E402  (the alternated whole-process timer)

NOTES = ["C3", "E3", "G3", "B3", "D4", "F#4", "A4", "C5"]


def score_text(seconds: float) -> str:
    lines = [f"[defaults]\nbeta = {100 / (2 * math.pi * 100)!r}\nvb = 0.2\nduration = {seconds}\n"]
    for i, note in enumerate(NOTES):
        lines.append(f'[[voice]]\nname = "v{i + 1}"\npitch = "{note}"\n')
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--seconds", type=float, default=60.0)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "long.toml"
        path.write_text(score_text(args.seconds))
        op = ["score", "--score", str(path), "--mix", "op.wav", "--force", "-q"]
        fdm = ["score", "--score", str(path), "--mix", "fdm.wav", "--force", "-q", "--method", "fdm"]
        a, b, ta, tb = alternate(op, fdm, args.runs, tmp)
    print(f"| `score` {len(NOTES)} voices x {args.seconds:g} s, `--mix` | {a:.2f} s | {b:.2f} s | "
          f"{b / a:.1f}x | runs {', '.join(f'{t:.2f}' for t in ta)} / {', '.join(f'{t:.2f}' for t in tb)} |")


if __name__ == "__main__":
    main()
