"""`bowsynth play`: the streaming engine as a JACK client (the JACK-Client package over libjack).

Ports: `<name>:midi_in` (MIDI in) and `<name>:out` (audio out). The engine (`stream.Stream`) is prepared in full
before the client activates; the process callback only hands the period's MIDI events to `Stream.process` and copies
its block into the port. The main thread prints a status line and waits for SIGINT / SIGTERM (the CLI's handlers
raise them here: exit 130 / 143) or for the server to go away (one line, exit 1).
"""

from __future__ import annotations

import math
import sys
import threading
import time

import numpy as np

from ..errors import BowsynthError, UsageError

class ServerGone(BowsynthError):
    """The JACK server shut down (or dropped the client) while playing."""


def open_client(name: str, server: str | None):
    """A JACK client, or a one-line BowsynthError saying how to start a server. libjack's own messages (several
    lines on stderr when no server runs) are silenced."""
    try:
        import jack
    except (ImportError, OSError):  # OSError: the package is there, libjack is not
        raise BowsynthError("bowsynth play needs JACK: install Debian's jackd2 (apt-get install jackd2; make setup "
                            "does) and the JACK-Client package (pip install JACK-Client)") from None
    jack.set_error_function(lambda msg: None)
    jack.set_info_function(lambda msg: None)
    try:
        return jack.Client(name, no_start_server=True, servername=server)
    except jack.JackOpenError:
        which, n = (f"named {server!r} ", f"-n {server} ") if server else ("", "")
        raise BowsynthError(f"no JACK server {which}is running: start one with `jackd {n}-d dummy -r 44100 -p 512 &` "
                            f"(no sound card needed; `-d alsa` plays through one)") from None


def percentiles_ms(times: np.ndarray) -> tuple[float, float, float]:
    if not len(times):
        return (math.nan,) * 3
    return tuple(float(v) * 1e3 for v in (np.percentile(times, 50), np.percentile(times, 99), times.max()))


def play(name: str = "bowsynth", server: str | None = None, connect=(), voices: int = 16, engine: str = "operator",
         model=None, a4: float = 440.0, amp: float | None = None, bend_range: float = 2.0, status=None,
         status_every: float = 1.0, windows: str | None = None) -> int:
    """Run the instrument until a signal (KeyboardInterrupt / Terminated propagate, after the summary) or until the
    server goes away (ServerGone). status: a function taking one line (the status line, then the summary)."""
    from ..music.engine_tuning import LIVE_WINDOWS, check_windows
    from .stream import AMP, Stream

    windows = check_windows(windows, LIVE_WINDOWS)
    if isinstance(voices, bool) or not isinstance(voices, int) or voices < 1:
        raise UsageError(f"--voices must be a whole number >= 1, got {voices!r}")
    say = status or (lambda line: print(line, file=sys.stderr, flush=True))
    client = open_client(name, server)
    gone = threading.Event()
    why_gone: list = []
    xruns = [0]
    try:
        rate, period = client.samplerate, client.blocksize
        first = ("" if windows == "free" or engine != "operator" else
                 f" (--windows {windows}: a first start measures the bow of each velocity the model plays, 0.5-1.5 "
                 f"minutes; later starts read it from the cache)")
        say(f"bowsynth: preparing {voices} voice(s), {engine} at {rate} Hz, {period}-frame periods{first} ...")
        stream = Stream(sample_rate=rate, block=max(period, 256), voices=voices, engine=engine, model=model, a4=a4,
                        amp=AMP if amp is None else amp, bend_range=bend_range, windows=windows)
        midi_in = client.midi_inports.register("midi_in")
        out = client.outports.register("out")
        chunk = stream.block

        @client.set_process_callback
        def process(frames):
            buf = out.get_array()
            events = [(off, bytes(data)) for off, data in midi_in.incoming_midi_events()]
            if frames <= chunk:
                buf[:] = stream.process(frames, events)
                return
            done = 0  # a period longer than the prepared block (the server's buffer size grew): in pieces
            while done < frames:
                n = min(chunk, frames - done)
                part = [(off - done, d) for off, d in events if done <= off < done + n]
                buf[done:done + n] = stream.process(n, part)
                done += n

        def on_xrun(delay):
            xruns[0] += 1

        def on_shutdown(status, reason):
            why_gone.append(reason)
            gone.set()

        client.set_xrun_callback(on_xrun)
        client.set_shutdown_callback(on_shutdown)
        client.activate()
        try:
            for port in connect:
                _connect(client, out, port)
        except BaseException:
            client.deactivate()
            raise
        say(f"bowsynth: playing as {client.name} ({client.name}:midi_in -> {client.name}:out"
            + (f" -> {', '.join(connect)}" if connect else "") + "); Ctrl-C to stop")
        t0 = time.monotonic()
        tty = sys.stderr.isatty()
        try:
            while not gone.wait(status_every):
                line = _status(stream, xruns[0], period, rate)
                if tty and status is None:
                    print("\r" + line, end="", file=sys.stderr, flush=True)
                else:
                    say(line)
        finally:
            if tty and status is None:
                print(file=sys.stderr)
            say(_summary(stream, xruns[0], period, rate, time.monotonic() - t0))
        raise ServerGone(f"the JACK server went away while playing ({(why_gone or ['no reason given'])[0].strip()})"
                         f"; start it again and rerun bowsynth play")
    finally:
        if not gone.is_set():
            try:
                client.deactivate()
            except Exception:
                pass
            client.close()


def _connect(client, out, port: str) -> None:
    import jack

    names = [p.name for p in client.get_ports(is_audio=True, is_input=True)]
    if port not in names:
        shown = ", ".join(names[:6]) + (" ..." if len(names) > 6 else "") or "none"
        raise UsageError(f"--connect {port}: no such audio input port on the JACK server (audio inputs: {shown})")
    try:
        client.connect(out, port)
    except jack.JackError as e:
        raise BowsynthError(f"--connect {port}: JACK refused the connection ({e})") from None


def _status(stream, xruns: int, period: int, rate: int) -> str:
    p50, p99, mx = percentiles_ms(stream.callback_times())
    c = stream.counts
    return (f"voices {stream.voices_sounding():3d}/{stream.n_voices}  callback p50 {p50:.2f} p99 {p99:.2f} max "
            f"{mx:.2f} ms of {1e3 * period / rate:.2f}  xruns {xruns}  notes {c['notes']}  dropped "
            f"{c['dropped_busy'] + c['dropped_bytes']}")


def _summary(stream, xruns: int, period: int, rate: int, seconds: float) -> str:
    p50, p99, mx = percentiles_ms(stream.callback_times())
    c = stream.counts
    extra = ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in c.items() if v and k != "notes")
    return (f"bowsynth: played {seconds:.1f} s, {c['notes']} note(s), xruns {xruns}; callback p50 {p50:.3f} / p99 "
            f"{p99:.3f} / max {mx:.3f} ms against the {1e3 * period / rate:.2f} ms period"
            + (f"; {extra}" if extra else ""))
