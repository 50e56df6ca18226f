"""Benchmarks: wall time per second of audio against error, for the FDM and the operators."""

from __future__ import annotations

import statistics
import time

import numpy as np

from .fdm import fdm_batch, render_fdm
from .scene import Scene


def _median_time(fn, repeats: int) -> float:
    fn()  # warm: compile, caches
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def bench_fdm(quick: bool = False) -> list[dict]:
    """Single-voice real-time factor at 44.1 kHz and 4.41 MHz, and batch throughput for 4096 initial states."""
    rows = []
    reps = 3 if quick else 7
    for label, dur, os_ in (("single voice, 44.1 kHz", 2.0 if quick else 10.0, 1),
                            ("single voice, 4.41 MHz (x100)", 0.05 if quick else 0.5, 100)):
        s = Scene(fb=100, duration=dur)
        sec = _median_time(lambda: render_fdm(s, oversample=os_), reps)
        rows.append({"case": label, "audio_s": dur, "wall_s": sec, "realtime_factor": dur / sec,
                     "steps_per_s": s.n_samples * os_ / sec})
    s = Scene(fb=100)
    rng = np.random.default_rng(0)
    n_states, n_steps = 4096, 441 if quick else 4410
    q0, p0 = rng.uniform(-0.2, 0.2, n_states), rng.uniform(-0.2, 0.2, n_states)
    sec = _median_time(lambda: fdm_batch(q0, p0, n_steps, 1, 1 / 44100, s.omega, s.fb, s.vb, s.a), 1 if quick else 3)
    rows.append({"case": f"batch, {n_states} states, 44.1 kHz", "audio_s": n_steps / 44100, "wall_s": sec,
                 "realtime_factor": n_states * n_steps / 44100 / sec, "steps_per_s": n_states * n_steps / sec})
    return rows


def fdm_table(rows: list[dict]) -> str:
    lines = ["| case | audio per voice (s) | wall (s) | real-time factor (all voices) | state-steps / s |", "|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['case']} | {r['audio_s']:g} | {r['wall_s']:.4f} | {r['realtime_factor']:.1f}x "
                     f"| {r['steps_per_s']:.3g} |")
    return "\n".join(lines)
