"""`bowsynth play`: the live instrument, a JACK client (bowsynth.live)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Optional

import typer

from ..errors import UsageError
from .app import LiveWindowsOpt, app

# The most slots: a bound on the pool (each slot holds its buffers, ~2.5 MB with the shipped models: 1 GB at 384), not
# on what the callback can play. What sounds at once is bounded by the callback's budget (live.budget.BUDGET: half of
# each period, from each voice's cost measured at start): on a 2-core machine ~115 voices low on the keyboard (each
# reserves its FDM release tail), 44 at MIDI 100, 28 at MIDI 108 (docs/live.md, "Real time").
MAX_VOICES = 384
# Polyphony by default: a chord of up to 64 keys (with the tails of the notes before it) plays as `score` renders it
# (at 16, a 32-key chord steals 16 of its own notes). A free slot costs the callback nothing (0.03 ms a block for 384
# free slots), only preparation before activation.
DEFAULT_VOICES = 64
MAX_GAIN_DB = 40.0  # x100 on the sum of the notes' q = w u (about 1 a voice at full bow): louder only clips
NAME_MAX = 63  # JACK's client names: 64 bytes with the terminating NUL


@app.command()
def play(
    name: str = typer.Option("bowsynth", "--name", help="The JACK client's name (its ports: NAME:midi_in, NAME:out)."),
    server: Optional[str] = typer.Option(None, "--server", help="The JACK server's name (jackd -n NAME); default: "
                                                                "the default server."),
    connect: Optional[list[str]] = typer.Option(None, "--connect", help="Connect NAME:out to this audio input port "
                                                                        "on start (repeatable), e.g. system:playback_1."),
    voices: int = typer.Option(DEFAULT_VOICES, "--voices", help="Voice slots (1..384): notes sounding at once, "
                                                                "release tails included; a note beyond them takes "
                                                                "the voice nearest its end (counted: stolen). The "
                                                                "real bound is the callback's budget, half of each "
                                                                "period from each voice's measured cost (high notes "
                                                                "cost more): a note-on beyond it is dropped "
                                                                "(counted: dropped)."),
    method: str = typer.Option("operator", "--method", "-m", help="Engine: operator (trained PI-DeepONet; notes it "
                                                                  "does not cover play the FDM) or fdm."),
    model: Optional[Path] = typer.Option(None, "--model", help="Operator model: a file or a model's name, as in "
                                                               "render (default: the validated model covering the "
                                                               "most velocities)."),
    a4: Optional[float] = typer.Option(None, "--a4", help="The tuning of A4 in Hz (default 440)."),
    gain: Optional[float] = typer.Option(None, "--gain", help="Output gain in dB on the sum of the notes' q = w u "
                                                              "(default -12: x0.25)."),
    bend_range: float = typer.Option(2.0, "--bend-range", help="Semitones at full pitch bend. CC1 (modulation) is "
                                                               "vibrato depth, +-50 cents at 127, at 5.5 Hz."),
    windows: Optional[str] = LiveWindowsOpt,
):
    """Play live: a JACK client taking MIDI on NAME:midi_in and sounding on NAME:out, until Ctrl-C or SIGTERM.

    Notes, velocities, CC2 (bow pressure) and CC11 (expression) map to the bow exactly as in `score` of a MIDI file,
    and each note is the note `score` would render, placed at its event's frame. Prints what the callback's budget
    holds, a status line (voices, predicted load against the budget, callback time against the period, xruns) and
    a summary at exit. See docs/live.md."""
    from ..engines import Engine, parse_choice
    from ..live.jack_client import play as run
    from ..music.notes import A4_HZ

    method = parse_choice(Engine, method, "--method").value
    if not 1 <= voices <= MAX_VOICES:
        raise UsageError(f"--voices must be 1..{MAX_VOICES} (the pool's slots; what sounds at once is bounded by the "
                         f"callback's budget, at most half of each period), got {voices}")
    if not name or len(name.encode()) > NAME_MAX or ":" in name or not name.isprintable():
        raise UsageError(f"--name must be 1..{NAME_MAX} printable bytes without ':' (a JACK client name), got "
                         f"{name[:40]!r}{'...' if len(name) > 40 else ''}")
    if gain is not None and not (math.isfinite(gain) and -400 < gain <= MAX_GAIN_DB):
        raise UsageError(f"--gain must be a number of dB in (-400, {MAX_GAIN_DB:g}] (louder only clips), got {gain}")
    if not 0 <= bend_range <= 24:
        raise UsageError(f"--bend-range must be 0..24 semitones, got {bend_range:g}")
    from ..music.engine_tuning import LIVE_WINDOWS, check_windows

    windows = check_windows(windows, LIVE_WINDOWS)
    amp = None if gain is None else 10.0 ** (gain / 20.0)
    run(name=name, server=server, connect=connect or (), voices=voices, engine=method, model=model,
        a4=A4_HZ if a4 is None else a4, amp=amp, bend_range=bend_range, windows=windows)
