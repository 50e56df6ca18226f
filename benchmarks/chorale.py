"""A chorale-sized piece as a user plays it: `score --mix` of a four-part MIDI file with the operator and with the FDM,
whole processes alternated with `bowsynth --help`, and how far the operator's mix sounds from the FDM's.

    PYTHONPATH=. .venv/bin/python benchmarks/chorale.py [--runs 3] [--keep DIR] [--model PATH] [--velocity 90]
                                                        [--windows locked,free]

The piece is written here (no corpus file ships with the repository) in the layout of a
chorale exported from a public corpus: MIDI type 1, a tempo track and four part tracks, every part on channel 1, one
velocity (90), 4 notes a beat at 76 bpm in four-part harmony (MIDI 42-76), 152 notes, ~25 s, with held notes, repeated
notes and unisons between parts. Prints Markdown: medians of the whole processes, notes played, and the median
log-spectral distance per 8192-sample frame between the two mixes (frames where the FDM's mix sounds).
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

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
# the processes a user runs read their modules' bytecode: a shell that sets PYTHONDONTWRITEBYTECODE (this machine's
# does) would have every process compile the edited modules again (~0.1 s of a chorale's process)
ENV = {**{k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}, "PYTHONPATH": str(ROOT)}
TPB = 480
# (soprano, alto, tenor, bass) per beat, MIDI numbers; a held note repeats its number with "-" in the next beat
PHRASES = [
    [(67, 62, 59, 43), (67, 64, 60, 48), (69, 64, 60, 45), (71, 62, 55, 55), (72, 64, 55, 48), (71, 62, 55, 50),
     (69, 60, 54, 50), (67, 59, 55, 43)],
    [(71, 62, 55, 55), (72, 64, 57, 57), (74, 66, 57, 50), (76, 67, 59, 52), (74, 66, 57, 54), (72, 64, 57, 45),
     (71, 62, 55, 47), (69, 62, 54, 50)],
    [(67, 62, 59, 55), (69, 64, 60, 52), (71, 62, 55, 47), (72, 64, 55, 48), (71, 62, 55, 50), (69, 60, 54, 42),
     (67, 59, 50, 43), (67, 59, 50, 43)],
]


def write_piece(path: Path, velocity: int = 90) -> int:
    import mido

    beats = [chord for phrase in PHRASES for chord in phrase] * 2
    mid = mido.MidiFile(type=1, ticks_per_beat=TPB)
    tempo = mido.MidiTrack([mido.MetaMessage("set_tempo", tempo=mido.bpm2tempo(76), time=0)])
    mid.tracks.append(tempo)
    notes = 0
    for part in range(4):
        tr = mido.MidiTrack([mido.MetaMessage("track_name", name=["Soprano", "Alto", "Tenor", "Bass"][part])])
        wait = 0
        i = 0
        while i < len(beats):
            n = beats[i][part]
            j = i + 1
            while j < len(beats) and beats[j][part] == n and part in (1, 2) and j - i < 2:
                j += 1  # inner parts hold a repeated note over two beats; soprano and bass re-strike
            tr.append(mido.Message("note_on", channel=0, note=n, velocity=velocity, time=wait))
            tr.append(mido.Message("note_off", channel=0, note=n, velocity=0, time=(j - i) * TPB - 20))
            wait, i, notes = 20, j, notes + 1
        mid.tracks.append(tr)
    mid.save(path)
    return notes


def run(args, cwd) -> tuple[float, str]:
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "bowsynth", *args], cwd=cwd, env=ENV, capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(f"bowsynth {' '.join(args)} failed: {r.stderr.strip()}")
    return time.perf_counter() - t0, r.stdout + r.stderr


def frame_lsd(x, ref, sr: int, floor_db: float = 80.0, n: int = 8192) -> float:
    """Median over frames (where ref sounds, within 40 dB of its loudest frame) of the log-spectral distance: the RMS
    dB difference of Welch spectra over the bins within floor_db of the frame's peak. At 80 dB (what `compare`
    uses) the bins between the harmonics, where float32 and float64 noise floors differ, weigh as much as the notes."""
    from scipy import signal as sps

    m = min(len(x), len(ref)) // n
    rms = np.array([np.sqrt(np.mean(ref[i * n:(i + 1) * n] ** 2)) for i in range(m)])
    out = []
    for i in (i for i in range(m) if rms[i] > rms.max() * 1e-2):
        _, px = sps.welch(x[i * n:(i + 1) * n], sr, nperseg=4096)
        _, pr = sps.welch(ref[i * n:(i + 1) * n], sr, nperseg=4096)
        keep = pr > pr.max() * 10 ** (-floor_db / 10)
        out.append(np.sqrt(np.mean((10 * np.log10((px[keep] + 1e-300) / pr[keep])) ** 2)))
    return float(np.median(out))


def mix_physical(path) -> np.ndarray:
    """A mix's samples in its own units (the sum of the notes' q): the file's peak normalisation undone with the gain
    in its metadata, so two mixes compare as rendered and not each at its own peak."""
    import json

    import soundfile as sf

    with sf.SoundFile(str(path)) as f:
        gain = float(json.loads(f.comment)["gain"])
        return f.read(dtype="float64") / gain


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--keep", type=Path, default=None, help="write the piece and the two mixes here")
    ap.add_argument("--velocity", type=int, default=90, help="every note's velocity (90: the corpus file's; 110-127: "
                    "loud notes, played by velocity-loud)")
    ap.add_argument("--model", type=Path, default=None,
                    help="the operator plays with this model (`train --score` of the piece, say) instead of its pick")
    ap.add_argument("--windows", default="locked", help="the operator's windows, one or more of locked, free "
                    "(score --windows; each an operator process of its own, alternated with the others)")
    args = ap.parse_args()
    modes = args.windows.split(",")
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(args.keep or tmp)
        d.mkdir(parents=True, exist_ok=True)
        n_notes = write_piece(d / "chorale.mid", args.velocity)
        procs = [f"operator {w}" for w in modes] + ["fdm"]
        times = {k: [] for k in ["help", *procs]}
        outs = {}
        for _ in range(args.runs):
            times["help"].append(run(["--help"], d)[0])
            for proc in procs:
                method, _, w = proc.partition(" ")
                pick = ["--model", str(args.model.resolve())] if args.model and method == "operator" else []
                t, out = run(["score", "--score", "chorale.mid", "--method", method, "--mix",
                              f"{proc.replace(' ', '-')}.wav", "--force", *pick, *(["--windows", w] if w else [])], d)
                times[proc].append(t)
                outs[proc] = out
        fd = mix_physical(d / "fdm.wav")
        med = {k: statistics.median(v) for k, v in times.items()}
        print(f"{n_notes} notes in the file; `score --mix`, medians of {args.runs} alternated runs (s)\n")
        print("| process | seconds | x --help | x the FDM's |\n|---|---|---|---|")
        for k in ("help", *procs):
            print(f"| {k} | {med[k]:.2f} | {med[k] / med['help']:.2f} | {med[k] / med['fdm']:.2f} |")
        for w in modes:
            op = mix_physical(d / f"operator-{w}.wav")
            lsd = {f: frame_lsd(op, fd, 44100, f) for f in (80.0, 60.0, 40.0)}
            print(f"\n{w} windows: median log-spectral distance per 8192-sample frame, operator mix against FDM mix, "
                  "over the bins within " + ", ".join(f"{f:.0f} dB of the peak: {v:.2f} dB" for f, v in lsd.items()))
        for proc in procs:
            said = [ln for ln in outs[proc].splitlines() if "wrote" in ln or "note" in ln.lower()][:3]
            print(f"\n{proc} said:\n" + "\n".join(f"    {ln}" for ln in said), file=sys.stderr)


if __name__ == "__main__":
    main()
