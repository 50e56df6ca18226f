"""Speed as a user feels it: import costs per command, whole-process CLI times (operator against the FDM, alternated),
the API's default path in one process, and a 100-voice score at 100 pitches.

    PYTHONPATH=. .venv/bin/python benchmarks/cli_speed.py [--runs 7] [--quick]

Each whole-process pair runs alternately (operator, fdm, operator, ...) so that a change in the machine's load hits
both; the medians are reported. Runs in a temporary directory (no ./models). Prints Markdown.
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

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as the CLI sets it (see cli.main): one process, small products

ROOT = Path(__file__).resolve().parents[1]
# the processes a user runs read their modules' bytecode: a shell that sets PYTHONDONTWRITEBYTECODE (this machine's
# does) would have every process compile the edited modules again (~0.1 s of a chorale's process)
ENV = {**{k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}, "PYTHONPATH": str(ROOT)}
PY = sys.executable


def run(args, cwd, env=None) -> float:
    t0 = time.perf_counter()
    r = subprocess.run([PY, "-m", "bowsynth", *args], cwd=cwd, env={**ENV, **(env or {})}, capture_output=True,
                       text=True)
    dt = time.perf_counter() - t0
    if r.returncode != 0:
        raise SystemExit(f"bowsynth {' '.join(args)} failed: {r.stderr.strip()}")
    return dt


def alternate(a, b, runs, cwd, env=None) -> tuple[float, float, list, list]:
    run(a, cwd, env), run(b, cwd, env)  # warm the file cache (and the pitch cache, where it is on)
    ta, tb = [], []
    for _ in range(runs):
        ta.append(run(a, cwd, env))
        tb.append(run(b, cwd, env))
    return statistics.median(ta), statistics.median(tb), ta, tb


def importtime(args, cwd, top: int = 6) -> tuple[float, list[tuple[str, float]]]:
    """Total import time of a command (ms) and its costliest third-party packages: each package's own cumulative
    import time, wherever in the tree it was first imported."""
    r = subprocess.run([PY, "-X", "importtime", "-m", "bowsynth", *args], cwd=cwd, env=ENV, capture_output=True,
                       text=True)
    per: dict[str, float] = {}
    total = 0.0
    for line in r.stderr.splitlines():
        if not line.startswith("import time:") or "cumulative" in line:
            continue
        _, cum_us, name = line.split("|")
        depth = len(name) - len(name.lstrip(" "))
        name = name.strip()
        if depth == 1:  # the roots of the tree: their sum is the whole import time
            total += int(cum_us) / 1e3
        if "." not in name and name not in per:
            per[name] = int(cum_us) / 1e3
    skip = {"bowsynth", "site", "encodings"}
    return total, sorted(((k, v) for k, v in per.items() if k not in skip and v >= 1.0), key=lambda kv: -kv[1])[:top]


def score_file(path: Path, voices: int = 100, duration: float = 1.0) -> Path:
    """voices at f0 = 100 * 2^(i / voices), F_B scaled with f0 to keep paper-fb100's F_B / w."""
    lines = [f"[defaults]\nduration = {duration}\nvb = 0.2\n"]
    for i in range(voices):
        f0 = 100 * 2 ** (i / voices)
        lines.append(f'[[voice]]\nname = "v{i:03d}"\nf0 = {f0!r}\nfb = {f0!r}\n')
    path.write_text("\n".join(lines))
    return path


def in_process(runs: int) -> tuple[float, float]:
    sys.path.insert(0, str(ROOT))
    from bowsynth import Scene, render_fdm, render_operator

    sc = Scene(fb=100, vb=0.2, duration=5.0)
    render_operator(sc), render_fdm(sc)  # first calls: model lookup, compiled FDM loaded
    to, tf = [], []
    for _ in range(runs):
        t0 = time.perf_counter()
        loop = render_operator(sc).info.loop
        to.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        render_fdm(sc)
        tf.append(time.perf_counter() - t0)
    return statistics.median(to), statistics.median(tf), loop


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--runs", type=int, default=7)
    ap.add_argument("--quick", action="store_true", help="3 runs, a 20-voice score")
    args = ap.parse_args()
    runs = 3 if args.quick else args.runs
    load = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        cwd = Path(tmp)
        print(f"machine: {os.cpu_count()} CPUs, load average {load:.2f} at the start; {runs} alternated runs each\n")
        print("## Import time per command (python -X importtime, ms; costliest packages imported by the command)\n")
        print("| command | imports ms | top costs |")
        print("|---|---|---|")
        score = score_file(cwd / "pitches.toml", voices=20 if args.quick else 100)
        cmds = {"--help": ["--help"], "presets": ["presets"], "models": ["models"],
                "render (operator, 5 s)": ["render", "--fb", "100", "-d", "5", "x.wav"],
                "render --method fdm": ["render", "--method", "fdm", "--fb", "100", "-d", "5", "x.wav"],
                "score (100 pitches)": ["score", "--score", str(score), "v"],
                "compare": ["compare", "x.wav"]}
        for label, c in cmds.items():
            total, top = importtime(c, cwd)
            print(f"| `{label}` | {total:.0f} | {', '.join(f'{k} {v:.0f}' for k, v in top)} |")
        print("\n## Whole process, medians (s)\n")
        print("| what | operator | fdm | operator / fdm |")
        print("|---|---|---|---|")
        renders = [["--fb", "100", "--vb", "0.2", "-d", "5"], ["--fb", "100", "--vb", "0.2", "-d", "1"],
                   # a bow only the soft range model covers (F_B / w 0.1), and a crescendo it follows
                   ["--f0", "440", "--fb", "276", "-d", "5"], ["--fb", "50@0,200@5", "--vb", "0.15", "-d", "5"]]
        for flags in renders:
            a = ["render", *flags, "x.wav"]
            mo, mf, _, _ = alternate(a, [*a[:1], "--method", "fdm", *a[1:]], runs, cwd)
            print(f"| `render {' '.join(flags)} x.wav` | {mo:.3f} | {mf:.3f} | {mo / mf:.2f} |")
        # --pitch solves f0 by FDM runs; what they measured is kept on disk (bowsynth.io.cache): warm, and switched off
        pitch = ["render", "--pitch", "A4", "--fb", "276", "-d", "1", "x.wav"]
        for label, env in (("pitch cache warm", {"BOWSYNTH_CACHE": str(cwd / "cache")}),
                           ("BOWSYNTH_CACHE=off: every process measures", {"BOWSYNTH_CACHE": "off"})):
            mo, mf, _, _ = alternate(pitch, [*pitch[:1], "--method", "fdm", *pitch[1:]], runs, cwd, env)
            print(f"| `{' '.join(pitch)}` ({label}) | {mo:.3f} | {mf:.3f} | {mo / mf:.2f} |")
        n = 20 if args.quick else 100
        for dur, extra in (("1", []), ("5", ["--mix"])):
            path = score_file(cwd / f"pitches-{dur}.toml", voices=n, duration=float(dur))
            a = ["score", "--score", str(path), *extra, "mix.wav" if extra else "v", "--force"]
            mo, mf, _, _ = alternate(a, [*a, "--method", "fdm"], runs, cwd)
            print(f"| `score` {n} voices x {dur} s at {n} pitches{', --mix' if extra else ' (a WAV each)'} | "
                  f"{mo:.3f} | {mf:.3f} | {mo / mf:.2f} (fdm / operator {mf / mo:.1f}x) |")
        os.chdir(cwd)
        io, if_, loop = in_process(runs)
        print(f"| in one process: `render_operator(scene)` (no model; {loop} loop) vs `render_fdm(scene)`, 5 s | {io:.4f} | "
              f"{if_:.4f} | {io / if_:.2f} (fdm / operator {if_ / io:.1f}x) |")
        print(f"\nload average at the end {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
