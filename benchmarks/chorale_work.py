"""The arithmetic of the chorale's operator render (against its 0.5x target): how many windows and voice-samples the
rollouts of `score --mix` roll, what that is in multiply-adds, and how long it would take at this machine's BLAS speed.

    PYTHONPATH=. .venv/bin/python benchmarks/chorale_work.py [--windows locked]

Plays benchmarks/chorale.py's piece in this process with every `rollout_states` call counted (voices, samples, windows,
the model's width), then prints per model the windows and voice-samples, the multiply-adds (analysis.bench's
window_macs and sample_macs) and the time at one core's float32 matrix-product speed measured in the same run
(analysis.bench.blas_gmacs), on one core and on two.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from collections import defaultdict
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))


def main() -> None:
    import numpy as np

    import bowsynth.engines.operator.engine as engine
    import bowsynth.engines.operator.rollout as rollout
    from bowsynth.analysis.bench import blas_gmacs, sample_macs, window_macs
    from chorale import write_piece

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--windows", default="locked")
    args = ap.parse_args()
    # per model: calls, voice-samples, windows, multiply-adds a window, a sample
    counts: dict = defaultdict(lambda: [0, 0, 0.0, 0, 0])
    real = rollout.rollout_states

    def counted(model, x0, n_samples, dtau, *a, **k):
        out = real(model, x0, n_samples, dtau, *a, **k)
        B = np.asarray(x0).reshape(-1, 2).shape[0]
        T = rollout.numpy_operator(model).window
        win = np.broadcast_to(np.asarray(T if k.get("window") is None else k["window"], float), (B,))
        spw = win / np.broadcast_to(np.asarray(dtau, float), (B,))
        c = counts[model.path.stem if model.path else model.meta.name]
        c[0] += 1
        c[1] += B * n_samples
        c[2] += float(np.sum(np.ceil(n_samples / spw)))
        c[3], c[4] = window_macs(model), sample_macs(model)
        return out
    rollout.rollout_states = engine.rollout_states = counted
    gmac = blas_gmacs(repeats=20)

    from bowsynth.cli.main import main as cli

    with tempfile.TemporaryDirectory() as d:
        mid = Path(d) / "chorale.mid"
        write_piece(mid)
        sys.argv = ["bowsynth", "score", "--score", str(mid), "--mix", str(Path(d) / "mix.wav"), "--force",
                    "--windows", args.windows]
        try:
            cli()
        except SystemExit:
            pass
    print(f"\nfloat32 matrix product (numpy's BLAS, one thread): {gmac:.1f} GMAC/s\n")
    print("| model | rollout calls | voice-samples | windows | MAC a window / a sample | GMAC |")
    print("|---|---|---|---|---|---|")
    total = 0.0
    for name, (calls, samples, windows, mw, ms) in counts.items():
        g = (windows * mw + samples * ms) / 1e9
        total += g
        print(f"| {name} | {calls} | {samples:,} | {windows:,.0f} | {mw:,} / {ms} | {g:.2f} |")
    print(f"\nin all {total:.2f} GMAC: {total / gmac:.3f} s on one core at the BLAS speed, "
          f"{total / gmac / 2:.3f} s on two")


if __name__ == "__main__":
    main()
