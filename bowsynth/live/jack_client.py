"""`bowsynth play`: the streaming engine as a JACK client (the JACK-Client package over libjack).

Ports: `<name>:midi_in` (MIDI in) and `<name>:out` (audio out). The engine (`stream.Stream`) is prepared in full
before the client activates; the process callback only hands the period's MIDI events to `Stream.process` and copies
its block into the port. The main thread prints a status line and waits for SIGINT / SIGTERM (the CLI's handlers
raise them here: exit 130 / 143) or for the server to go away (one line, exit 1). However it ends, the process
callback ends libjack's process thread itself before the client is closed (`_Ending`: libjack's own way of stopping
a thread is an asynchronous cancel, fatal to a thread inside Python).
"""

from __future__ import annotations

import math
import os
import sys
import threading
import time

import numpy as np

from ..errors import BowsynthError, UsageError, held

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


def play(name: str = "bowsynth", server: str | None = None, connect=(), voices: int = 64, engine: str = "operator",
         model=None, a4: float = 440.0, amp: float | None = None, bend_range: float = 2.0, status=None,
         status_every: float = 1.0, windows: str | None = None) -> int:
    """Run the instrument until a signal (KeyboardInterrupt / Terminated propagate, after the summary) or until the
    server goes away (ServerGone). status: a function taking one line (the status line, then the summary)."""
    import jack

    from ..music.engine_tuning import LIVE_WINDOWS, check_windows
    from .stream import AMP, Stream

    windows = check_windows(windows, LIVE_WINDOWS)
    if isinstance(voices, bool) or not isinstance(voices, int) or voices < 1:
        raise UsageError(f"--voices must be a whole number >= 1, got {voices!r}")
    say = status or (lambda line: print(line, file=sys.stderr, flush=True))
    client = open_client(name, server)
    end = _Ending()
    xruns = [0]
    stream = t0 = None
    tty = sys.stderr.isatty() and status is None
    try:
        rate, period = client.samplerate, client.blocksize
        first = ("" if windows == "free" or engine != "operator" else
                 f" (--windows {windows}: a first start measures the bow of each velocity the model plays, 0.5-1.5 "
                 f"minutes; later starts read it from the cache)")
        say(f"bowsynth: preparing {voices} voice(s), {engine} at {rate} Hz, {period}-frame periods{first} ...")
        stream = Stream(sample_rate=rate, block=max(period, 256), voices=voices, engine=engine, model=model, a4=a4,
                        amp=AMP if amp is None else amp, bend_range=bend_range, windows=windows)
        say(_budget_line(stream, period, rate))
        midi_in = client.midi_inports.register("midi_in")
        out = client.outports.register("out")
        chunk = stream.block

        @client.set_process_callback
        def process(frames):
            if end.tid is None:
                end.tid = threading.get_native_id()
            end.busy = True
            try:
                if end.stop:
                    # returning failure ends the client from its own thread, outside Python (_Ending)
                    out.get_array().fill(0.0)
                    if not end.seen:
                        end.seen_at, end.seen = time.monotonic(), True
                    raise jack.CallbackExit
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
            except jack.CallbackExit:
                raise
            except BaseException as e:  # a bug: the main thread reports it, the client ends as on a stop
                end.failed.append(e)
                end.stop = True
                end.wake.set()
                out.get_array().fill(0.0)
                raise jack.CallbackExit from None
            finally:
                end.busy = False

        def on_xrun(delay):
            end.notifying += 1
            xruns[0] += 1
            end.notifying -= 1

        def on_shutdown(status, reason):
            end.notifying += 1
            end.why_gone.append(reason)
            end.wake.set()
            end.notifying -= 1

        client.set_xrun_callback(on_xrun)
        client.set_shutdown_callback(on_shutdown)
        with held():  # a signal as activate() returns still finds the client known to be active
            client.activate()
            end.active = True
        for port in connect:
            _connect(client, out, port)
        say(f"bowsynth: playing as {client.name} ({client.name}:midi_in -> {client.name}:out"
            + (f" -> {', '.join(connect)}" if connect else "") + "); Ctrl-C to stop")
        t0 = time.monotonic()
        while not end.wake.wait(status_every):
            line = _status(stream, xruns[0], period, rate)
            if tty:
                print("\r" + line, end="", file=sys.stderr, flush=True)
            else:
                say(line)
        if end.failed:
            raise RuntimeError(f"the process callback failed: {end.failed[0]!r}") from end.failed[0]
        raise ServerGone(f"the JACK server went away while playing ({(end.why_gone or ['no reason given'])[0].strip()})"
                         f"; start it again and rerun bowsynth play")
    finally:
        # a signal here waits until the client is closed and the summary said (errors.held): a second Ctrl-C cannot
        # cut the ending half-way and leave libjack's threads running Python while the interpreter exits
        with held():
            end.close(client)
            if t0 is not None:
                if tty:
                    print(file=sys.stderr)
                say(_summary(stream, xruns[0], period, rate, time.monotonic() - t0))


STOP_WAIT = 2.0  # s: the longest the ending waits for the process thread to leave (a server that runs no cycle)
QUIET_WAIT = 0.02  # s: after the notification callbacks are unset, for one already under way to return


class _Ending:
    """What the process callback, the notification callbacks and the main thread share, and the ending itself.

    libjack ends a client's threads with pthread_cancel, asynchronously (JackPosixThread::Kill: jack_deactivate
    cancels the process thread, jack_client_close the notification thread). A thread cancelled while it runs Python
    (the process callback, an xrun callback) unwinds through the interpreter's and the compiled core's frames: the
    process then aborts ("terminate called without an active exception"), segfaults, or hangs on a lock the thread
    held. So nothing is cancelled while it runs Python: the main thread sets `stop`; at its next cycle the process
    callback returns failure (jack.CallbackExit), and libjack's process thread deactivates the client and exits on its
    own, in libjack's code (JackClient::End); the main thread waits for that thread to be gone (Linux: its task in
    /proc; elsewhere a fixed wait), unsets the notification callbacks (allowed once the client is inactive), lets one
    under way return, and only then deactivates (a no-op by then) and closes."""

    def __init__(self):
        self.stop = False  # read by the process callback every cycle
        self.active = False
        self.tid = None  # the process thread's native id, from its first callback
        self.wake = threading.Event()  # the main loop ends: the server went away, or the callback failed
        self.why_gone: list = []
        self.failed: list = []
        self.notifying = 0  # notification callbacks running Python now
        self.seen, self.seen_at = False, 0.0  # a process callback saw `stop` (when, by the monotonic clock)
        self.busy = False  # the process callback runs

    def _left(self) -> bool:
        """Has the process thread left libjack's cycle for good (after a callback that saw `stop`)?"""
        if self.tid is None:
            return False
        if os.path.isdir("/proc/self/task"):  # Linux: the thread's task is gone once it exited
            return not os.path.exists(f"/proc/self/task/{self.tid}")
        return self.seen and time.monotonic() - self.seen_at > 0.1

    def close(self, client) -> None:
        import jack

        self.stop = True
        if self.active:
            # the process thread leaves after its next cycle; when no cycle comes (a server gone or stalled) it
            # waits inside libjack once its callback has returned, where the cancel is what every client gets
            t0 = time.monotonic()
            while not self._left() and time.monotonic() - t0 < STOP_WAIT:
                if self.why_gone and not self.busy:
                    time.sleep(QUIET_WAIT)
                    break
                time.sleep(0.002)
        try:
            client.deactivate()  # at once when the process thread deactivated the client itself
            # inactive now: the notification thread runs no more Python once these are unset. JACK-Client has no call
            # that unsets a callback, so its cffi handles are used (private: where they are missing, the close below
            # is as it would be without them)
            lib, ffi = jack._lib, jack._ffi
            lib.jack_set_xrun_callback(client._ptr, ffi.NULL, ffi.NULL)
            lib.jack_on_info_shutdown(client._ptr, ffi.NULL, ffi.NULL)
        except Exception:
            pass
        t0 = time.monotonic()
        time.sleep(QUIET_WAIT)
        while self.notifying and time.monotonic() - t0 < STOP_WAIT:
            time.sleep(0.002)
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


BUDGET_NOTES = ((40, "E2"), (72, "C5"), (100, "E7"), (108, "C8"))  # what the start line says the budget holds


def _budget_line(stream, period: int, rate: int) -> str:
    """What bounds the callback: the budget, the measured cost model, and how many voices it holds at a few
    pitches (a voice reserves the most of its sustain and its FDM release tail; Stream.predicted_share)."""
    held = []
    for note, name in BUDGET_NOTES:
        share = stream.predicted_share(note)
        if share > 0 and math.isfinite(stream.budget):
            held.append(f"{min(int(stream.budget // share), stream.n_voices)} at {name}")
    return (f"bowsynth: callback budget {stream.budget:.0%} of each {1e3 * period / rate:.2f} ms period; a voice "
            f"costs {stream.costs} (measured): of {stream.n_voices} voice(s) it holds {', '.join(held) or 'all'} "
            f"(velocity 64); a note-on beyond it is dropped (counted)")


def _status(stream, xruns: int, period: int, rate: int) -> str:
    p50, p99, mx = percentiles_ms(stream.callback_times())
    c = stream.counts
    return (f"voices {stream.voices_sounding():3d}/{stream.n_voices}  load {stream.load:4.0%} of {stream.budget:.0%}  "
            f"callback p50 {p50:.2f} p99 {p99:.2f} max {mx:.2f} ms of {1e3 * period / rate:.2f}  xruns {xruns}  "
            f"notes {c['notes']}  dropped {c['dropped'] + c['dropped_busy'] + c['dropped_bytes']}"
            + (f"  shed {c['shed']}" if c['shed'] else ""))


def _summary(stream, xruns: int, period: int, rate: int, seconds: float) -> str:
    p50, p99, mx = percentiles_ms(stream.callback_times())
    c = stream.counts
    extra = ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in c.items() if v and k != "notes")
    return (f"bowsynth: played {seconds:.1f} s, {c['notes']} note(s), xruns {xruns}; callback p50 {p50:.3f} / p99 "
            f"{p99:.3f} / max {mx:.3f} ms against the {1e3 * period / rate:.2f} ms period"
            + (f"; {extra}" if extra else ""))
