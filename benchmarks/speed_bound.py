"""The best ratio any operator could reach against the FDM in the score targets of issues 11 and 12, measured.

    PYTHONPATH=. .venv/bin/python benchmarks/speed_bound.py [--runs 3] [--quick]

For each piece, three whole processes alternated (medians):
- the operator CLI as shipped;
- the operator CLI with its rollout replaced by a stub that returns silence at once (`rollout_states` answers zeros
  without any work, except for the physics check's two windows): an operator that costs nothing. Everything else runs as shipped: the interpreter, imports,
  score parsing, model lookup and physics check, the FDM bow-stop releases, DC removal, mixing, writing files;
- the FDM CLI (`--method fdm`).
fdm / stub is the ratio no operator can beat on this machine, whatever its network; the operator's own rollout
cost is operator - stub. Also the bare interpreter with the imports a render needs, the floor under every command.

Pieces: 100 voices x 1 s at 100 pitches (a WAV each, cli_speed.score_file) and 8 voices x 60 s
(a chord C3-C5, --mix, long_score.score_text).
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
from cli_speed import ENV, PY, score_file  # noqa: E402
from long_score import score_text  # noqa: E402

STUB = """
import sys
import numpy as np
import bowsynth.engines.operator.engine as r  # render_operator calls rollout_states through this name

real = r.rollout_states

def silent(model, x0, n_samples, dtau, check_domain=True, loop="auto", params=None):
    if n_samples < 2000:  # the physics check's two windows (and a one-sample call): as shipped
        return real(model, x0, n_samples, dtau, check_domain, loop, params)
    B = len(np.asarray(x0).reshape(-1, 2))
    return (np.zeros((B, n_samples), np.float32), np.zeros((B, n_samples), np.float32),
            np.tile(np.array([-1, 0], np.int64), (B, 1)))

r.rollout_states = silent
sys.argv = ["bowsynth", *sys.argv[1:]]
from bowsynth.cli.main import main
main()
"""
FLOOR = "import numpy, soundfile, typer, rich"


def timed(cmd: list[str], cwd) -> float:
    t0 = time.perf_counter()
    r = subprocess.run(cmd, cwd=cwd, env=ENV, capture_output=True, text=True)
    dt = time.perf_counter() - t0
    if r.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed: {r.stderr.strip()}")
    return dt


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--quick", action="store_true", help="20 voices x 1 s and 8 voices x 10 s")
    args = ap.parse_args()
    print(f"machine: {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f} at the start; "
          f"{args.runs} alternated runs, medians (s)\n")
    print("| piece | operator | operator with a zero-cost rollout | fdm | fdm / operator | fdm / zero-cost "
          "(the best any operator could do) | target |")
    print("|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        cwd = Path(tmp)
        n, secs = (20, 10.0) if args.quick else (100, 60.0)
        many = score_file(cwd / "many.toml", voices=n, duration=1.0)
        long = cwd / "long.toml"
        long.write_text(score_text(secs))
        pieces = [(f"{n} voices x 1 s at {n} pitches, a WAV each", ["score", "--score", str(many), "v", "--force",
                                                                     "-q"], "5x"),
                  (f"8 voices x {secs:g} s, --mix", ["score", "--score", str(long), "--mix", "m.wav", "--force",
                                                     "-q"], "10x")]
        for label, cmd, target in pieces:
            variants = {"op": [PY, "-m", "bowsynth", *cmd], "stub": [PY, "-c", STUB, *cmd],
                        "fdm": [PY, "-m", "bowsynth", *cmd, "--method", "fdm"]}
            for v in variants.values():  # warm the file cache
                timed(v, cwd)
            times = {k: [] for k in variants}
            for _ in range(args.runs):
                for k, v in variants.items():
                    times[k].append(timed(v, cwd))
            m = {k: statistics.median(t) for k, t in times.items()}
            print(f"| {label} | {m['op']:.2f} | {m['stub']:.2f} | {m['fdm']:.2f} | {m['fdm'] / m['op']:.1f}x | "
                  f"{m['fdm'] / m['stub']:.1f}x | {target} |", flush=True)
        floor = statistics.median(timed([PY, "-c", FLOOR], cwd) for _ in range(max(args.runs, 5)))
        print(f"\nThe interpreter with `{FLOOR}` alone: {floor:.2f} s.")


if __name__ == "__main__":
    main()
