"""Benchmarks of the live instrument (results in docs/BENCHMARKS.md, "Playing live").

    python benchmarks/live.py callback [--seconds 5] [--windows free|locked]   # Stream.process times at 1/16/64/256
                                                                              # voices, both engines
    python benchmarks/live.py jack                       # melody + 32-note chord through jackd: xruns, NCC, lag, cents
    python benchmarks/live.py hold --voices 64 --seconds 60   # 64 held voices through jackd: xruns
    python benchmarks/live.py curves                     # vibrato and glissando against a x100 FDM, per 100 ms frame

The JACK runs start their own dummy-driver server (44.1 kHz, 512 frames) and end it by its process id.
"""

from __future__ import annotations

import argparse
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))
RATE, PERIOD = 44100, 512
MODEL = "soft-range"


def callback(seconds: float, windows: str = "free") -> None:
    from bowsynth.live import Stream

    period_ms = 1e3 * PERIOD / RATE
    print(f"operator windows: {windows}\n")
    print("| engine | voices | p50 ms | p99 ms | max ms | max / period | note-on blocks max ms |")
    print("|---|---|---|---|---|---|---|")
    for engine in ("operator", "fdm") if windows == "free" else ("operator",):
        for nv in (1, 16, 64, 256):
            s = Stream(block=PERIOD, voices=nv, engine=engine, model=MODEL if engine == "operator" else None,
                       busy_fraction=10.0, windows=windows, budget=math.inf)  # every voice sounds: its cost measured
            notes = [40 + (5 * i) % 49 for i in range(nv)]  # E2 .. E6, spread (channel i % 16: no key twice)
            t_on = []
            for b in range(0, nv, 8):  # 8 note-ons a block (a chord of 8 keys)
                t0 = time.perf_counter()
                s.process(PERIOD, [(i, bytes((0x90 | (j % 16), notes[j], 64))) for i, j in enumerate(range(b,
                                                                                                            min(nv, b + 8)))])
                t_on.append(time.perf_counter() - t0)
            n0 = s.n_times
            for _ in range(int(seconds * RATE / PERIOD)):
                s.process(PERIOD, [])
            t = s.callback_times()[n0:] * 1e3
            assert s.voices_sounding() == nv, (s.voices_sounding(), s.counts)
            print(f"| {engine} | {nv} | {np.percentile(t, 50):.3f} | {np.percentile(t, 99):.3f} | {t.max():.3f} | "
                  f"{t.max() / period_ms:.2f} | {1e3 * max(t_on):.2f} |", flush=True)


class Server:
    def __init__(self):
        import test_live as T

        self.T = T
        self.name = f"bench-{os.getpid()}"
        self.proc = subprocess.Popen(["jackd", "-n", self.name, "-d", "dummy", "-r", str(RATE), "-p", str(PERIOD)],
                                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        T._wait_server(self.name, self.proc)

    def close(self):
        self.T._stop(self.proc)


def jack_melody() -> None:
    import test_live as T
    from bowsynth.metrics import f0_estimate
    from bowsynth.music.notes import midi_to_hz

    srv = Server()
    try:
        p = T.Player(srv.name, "--model", MODEL, "--voices", "40")
        p.wait_ready()
        time.sleep(0.5)
        melody = [(69, 0.1), (71, 0.6), (72, 1.1), (74, 1.6), (76, 2.1), (77, 2.6), (79, 3.1), (81, 3.6)]
        ev = [(t, T.on(n)) for n, t in melody] + [(t + 0.45, T.off(n)) for n, t in melody]
        chord = [45 + i for i in range(32)]  # A2 .. E5, 32 keys at once
        ev += [(4.2, T.on(n, 50)) for n in chord] + [(5.7, T.off(n)) for n in chord]
        ev.sort(key=lambda e: e[0])
        rec, frames = T.perform(srv.name, ev, 6.3, skips_ok=True)
        code, out = p.stop()
        print(T._summary(out))
        evd = [d for _, d in ev]
        with tempfile.TemporaryDirectory() as tmp:
            ref = T._offline(Path(tmp), list(zip(frames, evd)), len(rec))
        lags = [int(np.argmax([np.dot(rec[2000:-2000], ref[2000 - l:len(ref) - 2000 - l]) for l in range(0, 1024)]))]
        a, b = T._highpass(rec), T._highpass(ref)
        cut = int(4.15 * RATE)  # the melody, then the chord
        for name, sl in (("melody", slice(0, cut)), ("chord", slice(cut, len(rec))), ("whole", slice(0, len(rec)))):
            print(f"{name}: lag {lags[0]} samples; NCC after a 20 Hz high-pass {100 * np.corrcoef(a[sl], b[sl])[0, 1]:.5f}"
                  f" %; max |live - offline| {np.max(np.abs(rec[sl] - ref[sl])):.2e} of peak {np.max(np.abs(ref)):.3f}")
        # latency: per note-on, the first sample where the recording departs from the offline render of the same
        # events without that note (its note-off dropped too), counted from the event's frame
        import test_stream as S
        from bowsynth.live.stream import AMP, DC_HZ

        on_frames = [f for f, d in zip(frames, evd) if d[0] & 0xF0 == 0x90]
        lat = []
        for k, f in enumerate(on_frames[:len(melody)] + [on_frames[len(melody)]]):
            note = evd[[i for i, d in enumerate(evd) if d[0] & 0xF0 == 0x90][k]][1]
            drop = [(fr, d) for fr, d in zip(frames, evd) if d[1] != note or (k >= len(melody) and d[1] not in chord)]
            if k >= len(melody):  # the chord as a whole
                drop = [(fr, d) for fr, d in zip(frames, evd) if not (d[1] in chord and fr >= f)]
            with tempfile.TemporaryDirectory() as tmp:
                other = S.offline(Path(tmp), drop, len(rec), "operator", AMP, 1.0 - 2.0 * math.pi * DC_HZ / RATE)
            lat.append(int(np.flatnonzero(np.abs(rec[f - 200:] - other[f - 200:]) > 1e-6)[0]) - 200)
        print("note-on to its first sample (samples): melody " + ", ".join(map(str, lat[:-1])) + f"; the chord {lat[-1]}")
        cs = []
        for (n, t), f in zip(melody, on_frames):
            body = rec[f + int(0.15 * RATE):f + int(0.45 * RATE)]
            cs.append(1200 * math.log2(f0_estimate(body, RATE, tail=1.0) / midi_to_hz(n)))
        print("melody cents from ET (last 0.3 s of each 0.45 s note): " + ", ".join(f"{c:+.3f}" for c in cs))
    finally:
        srv.close()


def hold(voices: int, seconds: float) -> None:
    import test_live as T

    srv = Server()
    try:
        p = T.Player(srv.name, "--model", MODEL, "--voices", str(voices))
        p.wait_ready()
        time.sleep(0.5)
        notes = [40 + (5 * i) % 49 for i in range(voices)]
        ev = [(0.02 * i, T.on(n, 64, i % 16)) for i, n in enumerate(notes)]
        T.perform(srv.name, ev, 1.5, skips_ok=True)
        time.sleep(seconds)
        code, out = p.stop()
        print(T._summary(out))
    finally:
        srv.close()


def curves(model: str = MODEL) -> None:
    """Vibrato (+-30 cents, 5.5 Hz) and an octave glissando on A3, F_B / w 0.159, v_B 0.2, against a x100 FDM of the
    same curve: per 100 ms frame the pitch (zero crossings) and harmonics 1-6 (each frame's FFT peaks)."""
    from bowsynth import Scene
    from bowsynth.engines.fdm import render_fdm
    from bowsynth.metrics import f0_estimate
    from bowsynth.engines.operator.engine import render_operator

    beta, vb, f0 = 0.1591549, 0.2, 220.0 / 0.9131957277611572  # A3 tuned with the bow's sounding ratio
    t = np.arange(0.0, 3.0, 0.005)
    vib = [(float(x), f0 * 2 ** (30 * math.sin(2 * math.pi * 5.5 * x) * (x > 0.5) / 1200)) for x in t]
    gl = [(0.0, f0), (1.0, f0), (2.0, 2 * f0), (3.0, 2 * f0)]
    held = [(0.0, f0)]  # the control: the same note held (the model's own error, no curve)
    for name, pts in (("vibrato +-30 cents 5.5 Hz from 0.5 s", vib), ("octave glissando 1-2 s", gl),
                      ("held A3 (control)", held)):
        sc = Scene(f0=pts if len(pts) > 1 else pts[0][1], fb=[(x, beta * 2 * math.pi * f) for x, f in pts] if
                   len(pts) > 1 else beta * 2 * math.pi * f0, vb=vb, duration=3.0)
        t0 = time.perf_counter()
        truth = render_fdm(sc, oversample=100)
        tt = time.perf_counter() - t0
        rows = {f"operator ({model})": render_operator(sc, model=model), "fdm (audio rate)": render_fdm(sc)}
        print(f"{name}: x100 FDM {tt:.1f} s")
        for eng, r in rows.items():
            dc, dh = [], []
            for a in np.arange(0.5, 2.9, 0.1):
                sl = slice(int(a * RATE), int((a + 0.1) * RATE))
                x, y = r.q[sl].astype(float), truth.q[sl].astype(float)
                dc.append(1200 * math.log2(f0_estimate(x, RATE, tail=1.0) / f0_estimate(y, RATE, tail=1.0)))
                dh.append(_harm_db(x, y))
            dc, dh = np.abs(dc), np.array(dh)
            print(f"  {eng}: pitch |cents| per frame median {np.median(dc):.3f} max {dc.max():.3f}; harmonics 1-6 "
                  f"|dB| median {np.median(dh):.3f} max {dh.max():.3f}")


def _harm_db(x, y, n=6):
    """Max |dB| difference of harmonics 1..n (each relative to its signal's fundamental) between two frames, from
    Hann-windowed FFT peaks around multiples of y's pitch."""
    from bowsynth.metrics import f0_estimate

    f = f0_estimate(y, RATE, tail=1.0)
    nfft = 1 << 16
    w = np.hanning(len(x))
    X, Y = np.abs(np.fft.rfft(x * w, nfft)), np.abs(np.fft.rfft(y * w, nfft))
    fq = np.fft.rfftfreq(nfft, 1 / RATE)

    def levels(S):
        out = []
        for h in range(1, n + 1):
            band = (fq > (h - 0.4) * f) & (fq < (h + 0.4) * f)
            out.append(20 * np.log10(S[band].max()))
        return np.array(out) - out[0]
    lx, ly = levels(X), levels(Y)
    keep = ly > -50
    return float(np.max(np.abs(lx - ly)[keep]))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("what", choices=["callback", "jack", "hold", "curves"])
    ap.add_argument("--seconds", type=float, default=None)
    ap.add_argument("--voices", type=int, default=64)
    ap.add_argument("--model", default=MODEL)
    ap.add_argument("--windows", default="free", choices=["free", "locked"], help="callback: the operator's windows")
    a = ap.parse_args()
    if a.what == "callback":
        callback(a.seconds or 5.0, a.windows)
    elif a.what == "jack":
        jack_melody()
    elif a.what == "hold":
        hold(a.voices, a.seconds or 60.0)
    else:
        curves(a.model)


if __name__ == "__main__":
    main()
