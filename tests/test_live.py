"""`bowsynth play` driven for real: a JACK server of its own (jackd's dummy driver, 44.1 kHz, 512-frame periods), the
player as a subprocess, and a test client that sends MIDI to bowsynth:midi_in and records bowsynth:out.

The sender and the recorder are two JACK clients, so the graph is sender -> bowsynth -> recorder with no cycle: all
three run in the same period, and a take is timed by the frames the graph processed (a note-on sent for frame f
is heard from frame f on; `perform`). No timing is asserted here (docs/BENCHMARKS.md has the callback times), nor
the server's xrun count (the whole graph's, start-up included); what was lost shows in the sample-for-sample
comparisons.
"""

from __future__ import annotations

import gc
import itertools
import os
import random
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

jack = pytest.importorskip("jack", reason="the JACK-Client package is not installed (make setup installs it)")
if shutil.which("jackd") is None:
    pytest.skip("jackd is not installed (make setup installs Debian's jackd2)", allow_module_level=True)

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(Path(__file__).resolve().parent))
RATE, PERIOD = 44100, 512
MODEL = "soft-range"
_names = itertools.count()


def _env():
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    return env


def _quiet():
    jack.set_error_function(lambda m: None)
    jack.set_info_function(lambda m: None)


def _wait_server(name: str, proc, timeout: float = 15.0) -> None:
    _quiet()
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        if proc.poll() is not None:
            raise RuntimeError(f"jackd exited with {proc.returncode}")
        try:
            c = jack.Client("probe", no_start_server=True, servername=name)
            c.close()
            return
        except jack.JackOpenError:
            time.sleep(0.1)
    raise RuntimeError("jackd did not come up")


def _stop(proc) -> None:
    """End a process we started, by its id."""
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


@pytest.fixture
def jackd():
    """A dummy-driver JACK server with a name of its own, ended by its process id."""
    name = f"bowsynth-test-{os.getpid()}-{next(_names)}"
    proc = subprocess.Popen(["jackd", "-n", name, "-d", "dummy", "-r", str(RATE), "-p", str(PERIOD)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        _wait_server(name, proc)
        yield name, proc
    finally:
        _stop(proc)


class Player:
    """`bowsynth play` as a subprocess on the test server."""

    def __init__(self, server: str, *args: str, name: str = "bowsynth"):
        self.name = name
        self.proc = subprocess.Popen([sys.executable, "-m", "bowsynth", "play", "--server", server, "--name", name,
                                      *args], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                     env=_env(), cwd=ROOT)
        self.server = server

    def wait_ready(self, timeout: float = 180.0) -> None:
        _quiet()
        c = jack.Client("watcher", no_start_server=True, servername=self.server)
        try:
            t0 = time.monotonic()
            while time.monotonic() - t0 < timeout:
                if self.proc.poll() is not None:
                    raise AssertionError(f"play exited early ({self.proc.returncode}): {self.proc.stdout.read()}")
                # the ports exist only once the engine is prepared (the client activates after that)
                if c.get_ports(f"{self.name}:out"):  # registered once the engine is prepared, just before activation
                    return
                time.sleep(0.2)
            raise AssertionError("play did not become ready")
        finally:
            c.close()

    def stop(self, sig=signal.SIGINT, timeout: float = 20.0) -> tuple[int, str]:
        self.proc.send_signal(sig)
        try:
            out, _ = self.proc.communicate(timeout=timeout)
        finally:
            _stop(self.proc)
        return self.proc.returncode, out


@pytest.fixture
def player(jackd):
    players = []

    def start(*args, name="bowsynth"):
        p = Player(jackd[0], *args, name=name)
        players.append(p)
        p.wait_ready()
        time.sleep(0.5)  # activation follows the port registration
        return p
    yield start
    for p in players:
        _stop(p.proc)


class LostCycle(Exception):
    """A cycle of the take ran the sender but not the recorder: a client (the player, or this test's Python sender)
    overran the period, and the server abandoned the rest of the graph for that cycle (a sender held up 50 ms in its
    callback: the player and the recorder skip its cycle, the server's clock jumps four periods). The player did not
    hear that cycle's events, so the take is no recording of the events sent; `played` plays it again."""


def perform(server: str, events, seconds: float, target: str = "bowsynth", lead: float = 0.3,
            stall: float | None = None, strict_from: float = 0.0, skips_ok: bool = False):
    """Send events [(seconds, bytes)] to target:midi_in and record target:out for `seconds`. Returns the recording
    and the frames (from its start) at which each event was delivered.

    Time is the graph's processed frames, not the server's clock: the clients run in the graph's order (sender,
    player, recorder) each cycle, so a cycle is known by its frame time and placed at the frames the sender had
    processed before it. A server clock that jumps (a dummy driver without real-time scheduling, woken late on a
    busy machine) changes nothing the player hears. A cycle the recorder missed from `strict_from` seconds on is a
    lost one (LostCycle; before it, the sender's own Python callback may be too slow: a flood of ~100 events a
    period loses cycles, and what the flood test asserts does not hang on them), unless skips_ok (a benchmark that
    counts the xruns: the take as it was, silence where cycles were lost). Python's cyclic garbage collector is off
    during the take: a full collection of this process's heap, late in the suite, could hold a callback past the
    period. stall: seconds into the take at which the sender's callback sleeps 50 ms (a lost cycle on purpose)."""
    _quiet()
    n = int(seconds * RATE)
    lead_n = int(round(lead * RATE))
    rec = np.full(lead_n + n + 4 * PERIOD, np.nan, np.float32)
    sender = jack.Client("sender", no_start_server=True, servername=server)
    recorder = jack.Client("recorder", no_start_server=True, servername=server)
    mout = sender.midi_outports.register("out")
    ain = recorder.inports.register("in")
    at: dict[int, int] = {}  # a cycle's frame time -> the frames the sender had processed before it
    state = {"pos": 0, "stalled": stall is None}
    sched = sorted(((int(round((lead + t) * RATE)), bytes(d)) for t, d in events), key=lambda e: e[0])
    idx = [0]
    stall_n = None if stall is None else lead_n + int(stall * RATE)

    @sender.set_process_callback
    def send(frames):
        mout.clear_buffer()
        pos = state["pos"]
        at[sender.last_frame_time] = pos
        while idx[0] < len(sched) and sched[idx[0]][0] < pos + frames:
            f, d = sched[idx[0]]
            mout.write_midi_event(f - pos, d)
            idx[0] += 1
        state["pos"] = pos + frames
        if not state["stalled"] and pos >= stall_n:
            state["stalled"] = True
            time.sleep(0.05)

    @recorder.set_process_callback
    def record(frames):
        pos = at.get(recorder.last_frame_time)
        if pos is not None and pos + frames <= len(rec):
            rec[pos:pos + frames] = ain.get_array()

    collecting = gc.isenabled()
    gc.disable()
    try:
        with sender, recorder:
            sender.connect(mout, f"{target}:midi_in")
            recorder.connect(f"{target}:out", ain)
            time.sleep(lead + seconds + 0.3)
            sender.deactivate()
            recorder.deactivate()
    finally:
        if collecting:
            gc.enable()
    out = rec[lead_n:lead_n + n]
    lost = np.isnan(out)
    lost[:int(strict_from * RATE)] = False
    if lost.any() and not skips_ok:
        raise LostCycle(f"{int(lost.sum())} frame(s) lost from frame {int(np.flatnonzero(lost)[0])} of the take")
    return np.nan_to_num(out, nan=0.0), [f - lead_n for f, _ in sched]


def played(player, server: str, args, events, seconds: float, sig=signal.SIGINT, tries: int = 5, **kw):
    """`bowsynth play ARGS` started, the events performed (perform), the player stopped with `sig`: (recording,
    frames, exit code, output). A take with a lost cycle (LostCycle) is played again by a fresh player, up to
    `tries` times: a callback of the instrument too slow for the period would lose cycles in every take and fail
    here, a hiccup of the machine does not. `stall` (perform's) applies to the first take only."""
    why = None
    for _ in range(tries):
        p = player(*args)
        try:
            rec, frames = perform(server, events, seconds, **kw)
        except LostCycle as e:
            p.stop(sig)
            why = e
            kw.pop("stall", None)
            continue
        code, out = p.stop(sig)
        return rec, frames, code, out
    pytest.fail(f"a cycle was lost in each of {tries} takes (last: {why})")


def on(note, vel=64, ch=0):
    return bytes((0x90 | ch, note, vel))


def off(note, ch=0):
    return bytes((0x80 | ch, note, 0))


MELODY = [(69, 0.1, 0.7), (72, 0.9, 0.7), (76, 1.7, 0.7), (74, 2.5, 0.7)]  # A4 C5 E5 D5


def melody_events():
    ev = []
    for n, t, d in MELODY:
        ev += [(t, on(n)), (t + d, off(n))]
    return ev


def _cents(x, f_ref):
    from bowsynth.metrics import f0_estimate

    return 1200 * np.log2(f0_estimate(x, RATE, tail=1.0) / f_ref)


def _write_midi(path: Path, frames_events):
    """A MIDI file whose tick is one frame (441 ticks per beat at 10 ms a beat): its events land on the frames given."""
    import mido

    mid = mido.MidiFile(ticks_per_beat=441)
    tr = mido.MidiTrack()
    mid.tracks.append(tr)
    tr.append(mido.MetaMessage("set_tempo", tempo=10000, time=0))
    last = 0
    for f, d in sorted(frames_events, key=lambda e: e[0]):
        tr.append(mido.Message.from_bytes(list(d)).copy(time=f - last))
        last = f
    mid.save(path)


def _offline(tmp_path, frames_events, n, method="operator"):
    """`bowsynth score --mix` of the same events (a fixed gain, DC kept: the sum of the notes' q), then the live
    output's scaling and causal DC blocker."""
    from bowsynth.engines.operator import voices as V
    from bowsynth.live.stream import AMP, DC_HZ
    import soundfile as sf

    mid = tmp_path / "same.mid"
    _write_midi(mid, frames_events)
    wav = tmp_path / "same.wav"
    r = subprocess.run([sys.executable, "-m", "bowsynth", "score", "--score", str(mid), "--mix", str(wav),
                        "--method", method, "--model", MODEL, "--dc", "keep", "--gain", "-24", "-q", "--force",
                        "--releases", "fdm", "--windows", "free"],  # live bow stops are the FDM's, its windows free
                       capture_output=True, text=True, env=_env(), cwd=ROOT)
    assert r.returncode == 0, r.stdout + r.stderr
    x = sf.read(str(wav), dtype="float64")[0] * 10 ** (24 / 20)  # -24 dB: a chord's sum would clip at 0 dB
    ref = np.zeros(n)
    ref[:min(n, len(x))] = AMP * x[:n]
    y = np.zeros(n, np.float32)
    V.dc_block(ref, n, 1.0 - 2.0 * np.pi * DC_HZ / RATE, np.zeros(2), y)
    return y


def _highpass(x, hz=20.0):
    from scipy.signal import butter, sosfiltfilt

    return sosfiltfilt(butter(4, hz, "highpass", fs=RATE, output="sos"), x)


def _summary(out: str) -> str:
    lines = [l for l in out.splitlines() if l.startswith("bowsynth: played")]
    assert lines, out
    return lines[-1]


def _reports_its_timing(summary: str) -> bool:
    """The summary says the xruns and the callback's times. Neither is asserted: the xrun count is the whole graph's
    (this test's Python recorder included), and a dummy driver without real-time scheduling on a busy 2-core machine
    reports some at start-up (CI saw 3 before the first note, with a worst callback of 0.22 ms); timings belong in
    docs/BENCHMARKS.md. Audio lost while playing shows in the sample-for-sample comparisons instead."""
    pattern = r"xruns \d+; callback p50 [\d.]+ / p99 [\d.]+ / max [\d.]+ ms against the [\d.]+ ms"
    return re.search(pattern, summary) is not None


def test_melody_plays_in_tune_on_time_and_as_score_renders_it(jackd, player, tmp_path):
    rec, frames, code, out = played(player, jackd[0], ("--model", MODEL, "--voices", "8"), melody_events(), 3.4)
    assert code == 130, out
    assert _reports_its_timing(_summary(out)), out
    from bowsynth.music.notes import midi_to_hz

    # onset: silence until the first note's frame, sound from that very frame (the voice starts at its event)
    f = frames[0]
    assert np.all(rec[:f] == 0) and rec[f + 1] != 0
    for (note, t, d), f in zip(MELODY, frames[0::2]):
        # pitch: the last 0.35 s of the sustain, within a cent of equal temperament
        body = rec[f + int((d - 0.35) * RATE):f + int(d * RATE)]
        assert abs(_cents(body, midi_to_hz(note))) < 1.0, note
    # the same events rendered offline by `bowsynth score`: the same samples (float32 rounding apart)
    ref = _offline(tmp_path, list(zip(frames, [d for _, d in melody_events()])), len(rec))
    lag = int(np.argmax([np.dot(rec[2000:-2000], ref[2000 - l:len(ref) - 2000 - l]) for l in range(0, 2 * PERIOD)]))
    assert lag == 0
    assert np.max(np.abs(rec - ref)) < 1e-4 * np.max(np.abs(ref))
    a, b = _highpass(rec), _highpass(ref)
    assert np.corrcoef(a, b)[0, 1] > 0.99


def test_a_take_that_lost_a_cycle_is_known(jackd, player):
    """The sender held up 50 ms mid-take: the server abandons that cycle's graph, and the take says so rather than
    passing off a recording the events never made (the tests above play such a take again)."""
    player("--model", MODEL, "--voices", "1")
    with pytest.raises(LostCycle):
        perform(jackd[0], [(0.1, on(69)), (0.8, off(69))], 1.0, stall=0.5)


def test_the_fdm_engine_plays_the_offline_fdm_notes(jackd, player, tmp_path):
    ev = [(0.0, on(62, 90)), (0.1, on(69, 40)), (0.6, off(62)), (0.9, off(69))]
    rec, frames, code, out = played(player, jackd[0], ("--method", "fdm", "--voices", "4"), ev, 1.4, signal.SIGTERM)
    assert code == 143, out
    # the notes as the Python API renders them offline, tuned with the truth's ratio as the live FDM tunes them
    # (`score --method fdm` tunes each pitch for the FDM's dispersion: docs/live.md)
    import test_stream as S
    from bowsynth.live.stream import AMP, DC_HZ

    ref = S.offline(tmp_path, list(zip(frames, [d for _, d in ev])), len(rec), "fdm", AMP,
                    1.0 - 2.0 * np.pi * DC_HZ / RATE)
    assert np.max(np.abs(rec - ref)) < 1e-5 * np.max(np.abs(ref))


def test_a_chord_sounds_every_note_and_more_notes_than_voices_steal(jackd, player):
    chord = [57, 61, 64]  # A3 C#4 E4
    ev = [(0.0, on(n)) for n in chord] + [(1.0, off(n)) for n in chord] + [(1.2, on(n)) for n in (60, 64, 67, 72)]
    ev += [(1.8, off(n)) for n in (60, 64, 67, 72)]
    rec, frames, code, out = played(player, jackd[0], ("--model", MODEL, "--voices", "3"), ev, 2.2)
    assert code == 130
    s = _summary(out)
    assert _reports_its_timing(s) and "stolen 1" in s, s
    from bowsynth.music.notes import midi_to_hz

    body = rec[frames[0] + int(0.5 * RATE):frames[0] + int(0.95 * RATE)]
    spec = np.abs(np.fft.rfft(body * np.hanning(len(body))))
    fq = np.fft.rfftfreq(len(body), 1 / RATE)
    for n in chord:
        hz = midi_to_hz(n)
        near = spec[(fq > hz * 0.98) & (fq < hz * 1.02)].max()
        assert near > 0.1 * spec.max(), n


def test_garbage_bytes_and_a_flood_of_notes_are_dropped_and_counted_and_time_is_kept(jackd, player):
    ev = [(0.0, b"\x45\x12\x00"), (0.0, b"\x90\x99\x40"), (0.01, b"\xf0\x01\x02\xf7"), (0.02, b"\x90\x40")]
    # 10,000 notes a second for 0.3 s, then a note that must still play in tune
    ev += [(0.05 + i / 10000, on(40 + i % 40, 30 + i % 90)) for i in range(3000)]
    ev += [(0.05 + i / 10000 + 0.0001, off(40 + i % 40)) for i in range(3000)]
    ev += [(0.6, bytes((0xB0, 123, 0))), (0.9, on(69)), (1.7, off(69))]
    rec, frames, code, out = played(player, jackd[0], ("--model", MODEL, "--voices", "8"), ev, 2.1, strict_from=0.6)
    assert code == 130
    s = _summary(out)
    assert "dropped bytes 3" in s, s
    from bowsynth.music.notes import midi_to_hz

    f = frames[-2]
    assert abs(_cents(rec[f + int(0.45 * RATE):f + int(0.8 * RATE)], midi_to_hz(69))) < 1.0
    assert np.all(np.isfinite(rec))


def test_sigterm_mid_note_ends_with_143_and_a_summary(jackd, player):
    _, _, code, out = played(player, jackd[0], ("--model", MODEL), [(0.0, on(60))], 0.3, signal.SIGTERM)  # still held
    assert code == 143
    assert "1 note(s)" in _summary(out)


CHORD = range(40, 72)  # 32 keys, E2 .. B4


def test_a_32_key_chord_after_a_melody_plays_as_score_renders_it_at_the_default_voices(jackd, player, tmp_path):
    """The default polyphony holds a 32-key chord (at 16 voices, 16 of its notes take the others' voices: NCC 72 %
    against score); a note-on past the block's time budget is caught up at the next block (tests/test_stream_chords.py),
    so the chord is score's on a loaded machine too."""
    ev = melody_events() + [(3.4, on(n)) for n in CHORD] + [(4.4, off(n)) for n in CHORD]
    rec, frames, code, out = played(player, jackd[0], ("--model", MODEL), ev, 4.8)
    assert code == 130, out
    s = _summary(out)
    assert "36 note(s)" in s and "stolen" not in s, s
    ref = _offline(tmp_path, list(zip(frames, [d for _, d in ev])), len(rec))
    a, b = _highpass(rec), _highpass(ref)
    cut = frames[2 * len(MELODY)]  # the chord's note-ons
    for part in (slice(0, cut), slice(cut, len(rec))):
        assert np.corrcoef(a[part], b[part])[0, 1] > 0.99, (part, s)
        rms = np.sqrt(np.mean(rec[part].astype(float) ** 2)) / np.sqrt(np.mean(ref[part].astype(float) ** 2))
        assert abs(rms - 1) < 0.01, (part, rms, s)


def burst_events(n: int = 6000, per_period: int = 60):
    """n MIDI messages, per_period a period: note-ons of the top three octaves (C6 .. B8) on all 16 channels, then
    their note-offs. At the most voices the callback's budget holds 15 (at B8) to 100 (at C6) of these notes and
    drops the rest (without it, all 384 sounded and a callback took 0.06-0.1 s of the 11.6 ms on a 2-core machine);
    each callback then takes about half the period, so a signal often finds it running, inside the interpreter or the
    compiled core."""
    keys = [(i % 16, 84 + (i // 16) % 36) for i in range(n // 2)]
    msgs = [on(k, 64, ch) for ch, k in keys] + [off(k, ch) for ch, k in keys]
    dt = PERIOD / RATE / per_period
    return [(i * dt, d) for i, d in enumerate(msgs)]


@pytest.mark.parametrize("sig,code,word", [(signal.SIGINT, 130, "interrupted"), (signal.SIGTERM, 143, "terminated")],
                         ids=["SIGINT", "SIGTERM"])
def test_a_signal_during_a_burst_at_the_most_voices_ends_cleanly(jackd, player, sig, code, word):
    """At the most voices, a burst of 6,000 MIDI messages through the server (most of its notes dropped by the
    callback's budget, the rest filling it), the signal at a random moment of it
    and again 0-50 ms later (a second Ctrl-C): the exit code, the summary, and the client gone from a server that
    still runs. libjack cancels its threads asynchronously when a client is deactivated or closed: a process thread
    cancelled inside the callback aborts the player ("terminate called without an active exception") or crashes it
    (SIGSEGV), 16 runs in 16 like these when jack_deactivate ends a running callback; the callback ends its thread
    itself instead (jack_client._Ending)."""
    from bowsynth.cli.play import MAX_VOICES

    p = player("--model", MODEL, "--voices", str(MAX_VOICES))
    ev = burst_events()
    at = random.uniform(0.05, ev[-1][0])
    again = random.uniform(0.0, 0.05)

    def send():
        p.proc.send_signal(sig)
        time.sleep(again)
        if p.proc.poll() is None:
            p.proc.send_signal(sig)
    timer = threading.Timer(0.3 + at, send)  # perform's lead: 0.3 s before the first event
    timer.start()
    try:
        perform(jackd[0], ev, ev[-1][0] + 0.2, skips_ok=True)
    finally:
        timer.join()
    try:
        out, _ = p.proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:
        pytest.fail(f"play hung after a signal {at:.3f} s into the burst")
    what = f"signal {at:.3f} s into the burst, again {again * 1e3:.0f} ms later:\n{out}"
    assert p.proc.returncode == code, what
    assert out.strip().splitlines()[-1] == word, what
    assert _reports_its_timing(_summary(out)), what
    assert not re.search(r"Traceback|terminate called|Fatal Python|Segmentation", out), what
    assert jackd[1].poll() is None
    _quiet()
    c = jack.Client("after", no_start_server=True, servername=jackd[0])
    try:
        assert not c.get_ports("bowsynth:"), what
    finally:
        c.close()


def test_no_server_is_one_line_saying_how_to_start_one(tmp_path):
    r = subprocess.run([sys.executable, "-m", "bowsynth", "play", "--server", f"none-{os.getpid()}"],
                       capture_output=True, text=True, env=_env(), cwd=ROOT, timeout=60)
    assert r.returncode == 1
    lines = (r.stdout + r.stderr).strip().splitlines()
    assert len(lines) == 1 and f"jackd -n none-{os.getpid()} -d dummy" in lines[0], lines


def test_bad_connect_port_and_zero_voices_are_refused(jackd):
    for args, what in ((["--connect", "nowhere:nothing"], "nowhere:nothing"), (["--voices", "0"], "--voices")):
        r = subprocess.run([sys.executable, "-m", "bowsynth", "play", "--server", jackd[0], "--model", MODEL, *args],
                           capture_output=True, text=True, env=_env(), cwd=ROOT, timeout=300)
        assert r.returncode == 2, r.stdout + r.stderr
        err = [l for l in r.stderr.strip().splitlines() if l.startswith("error")]
        assert len(err) == 1 and what in err[0], r.stderr


def test_the_server_going_away_is_one_line_and_exit_1(jackd, player):
    p = player("--model", MODEL)
    _stop(jackd[1])
    try:
        out, _ = p.proc.communicate(timeout=30)
    finally:
        _stop(p.proc)
    assert p.proc.returncode == 1, out
    err = [l for l in out.splitlines() if l.startswith("error")]
    assert len(err) == 1 and "went away" in err[0], out


@pytest.mark.parametrize("args,what", [(["--gain", "nan"], "--gain"), (["--gain", "inf"], "--gain"),
                                       (["--gain", "400"], "--gain"), (["--gain", "1e308"], "--gain"),
                                       (["--voices", "5000"], "--voices"), (["--voices", "100000"], "--voices"),
                                       (["--name", ""], "--name"), (["--name", "x" * 300], "--name"),
                                       (["--name", "a:b"], "--name")])
def test_play_refuses_what_no_callback_could_hold_before_it_starts(args, what):
    """A gain that is not a finite level or only clips, more voice slots than the pool holds (what sounds is bounded
    by the callback's budget), and a name JACK cannot take: one line, exit 2, before any server is asked (none runs
    here)."""
    r = subprocess.run([sys.executable, "-m", "bowsynth", "play", "--server", f"none-{os.getpid()}", *args],
                       capture_output=True, text=True, env=_env(), cwd=ROOT, timeout=120)
    assert r.returncode == 2, r.stdout + r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error") and what in lines[0], r.stderr


def test_high_notes_bent_two_octaves_up_play_finite_through_jack(jackd, player):
    """`play --bend-range 24`: a chord at MIDI 104-111, then the pitch wheel at its top (notes past 13 kHz) and a full
    vibrato, through a real jackd: the take is finite and bounded (perform counts a NaN sample as a lost cycle, and a
    player that streamed NaN loses every take), the player ends with its summary; a bend the budget cannot hold ends
    voices (`shed`) rather than the callback running late."""
    chord = range(104, 112)
    ev = [(0.0, on(n)) for n in chord] + [(0.4, bytes((0xE0, 0x7F, 0x7F))), (0.5, bytes((0xB0, 1, 127)))]
    ev += [(1.4, off(n)) for n in chord]
    rec, frames, code, out = played(player, jackd[0], ("--bend-range", "24"), ev, 1.8)
    assert code == 130
    s = _summary(out)
    assert _reports_its_timing(s) and "8 note(s)" in s, s
    assert np.all(np.isfinite(rec)) and np.max(np.abs(rec)) <= 1.0
    bent = rec[frames[1] + int(0.2 * RATE):frames[-1]]
    assert np.std(bent) > 0, "the bent chord is silent"
