"""`bowsynth play`: the live instrument, a JACK client (bowsynth.live)."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from ..errors import UsageError
from .app import LiveWindowsOpt, app


@app.command()
def play(
    name: str = typer.Option("bowsynth", "--name", help="The JACK client's name (its ports: NAME:midi_in, NAME:out)."),
    server: Optional[str] = typer.Option(None, "--server", help="The JACK server's name (jackd -n NAME); default: "
                                                                "the default server."),
    connect: Optional[list[str]] = typer.Option(None, "--connect", help="Connect NAME:out to this audio input port "
                                                                        "on start (repeatable), e.g. system:playback_1."),
    voices: int = typer.Option(16, "--voices", help="Polyphony: notes sounding at once; a note beyond them takes "
                                                    "the voice nearest its end."),
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
    and each note is the note `score` would render, placed at its event's frame. Prints a status line (voices,
    callback time against the period, xruns) and a summary at exit. See docs/live.md."""
    from ..engines import Engine, parse_choice
    from ..live.jack_client import play as run
    from ..music.notes import A4_HZ

    method = parse_choice(Engine, method, "--method").value
    if voices < 1:
        raise UsageError(f"--voices must be >= 1, got {voices}")
    if not 0 <= bend_range <= 24:
        raise UsageError(f"--bend-range must be 0..24 semitones, got {bend_range:g}")
    from ..music.engine_tuning import LIVE_WINDOWS, check_windows

    windows = check_windows(windows, LIVE_WINDOWS)
    amp = None if gain is None else 10.0 ** (gain / 20.0)
    run(name=name, server=server, connect=connect or (), voices=voices, engine=method, model=model,
        a4=A4_HZ if a4 is None else a4, amp=amp, bend_range=bend_range, windows=windows)
