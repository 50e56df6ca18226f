"""The command-line app and what its commands share: the consoles, the scene flags, one-line messages."""

from __future__ import annotations

import typer
from rich.console import Console

from ..io.text import num

app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
                  help="bowsynth: a bowed mass-spring synthesizer driven by a physics-informed DeepONet.")


err = Console(stderr=True, highlight=False, emoji=False)  # ":100:" in a message is text, not an emoji
out = Console(highlight=False, emoji=False)
run_state = {"debug": False, "signal": None}
# Scene flags shared by render / train / compare. None means "take the preset's value, else the default".
PresetOpt = typer.Option(None, "--preset", help="Preset scene name (see `bowsynth presets`); flags override it.")
F0Opt = typer.Option(None, "--f0", help="Pitch of the mass-spring, Hz (default 100).")
FbOpt = typer.Option(None, "--fb", help="Bow force per unit mass F_B, m/s^2 (default 100); or a gesture as "
                                         "VALUE@SECONDS pairs, e.g. 50@0,200@1 (linear between, held outside).")


VbOpt = typer.Option(None, "--vb", help="Bow velocity v_B, m/s (default 0.2); or a gesture, e.g. 0.2@0,0.05@0.1 "
                                         "(a bow stop).")


AOpt = typer.Option(None, "--a", help="Friction shape a, s^2/m^2 (default 100).")
DurOpt = typer.Option(None, "--duration", "-d", help="Duration, s (default 1.0).")
RateOpt = typer.Option(None, "--sample-rate", "--sr", help="Sample rate, Hz (default 44100).")
Q0Opt = typer.Option(None, "--q0", help="Initial q = w u(0), m/s (default 0).")
P0Opt = typer.Option(None, "--p0", help="Initial velocity u_t(0), m/s (default 0).")
PitchOpt = typer.Option(None, "--pitch", help="The pitch you hear, Hz or a note name (A4, C#3, Bb2; C0..B8): solves "
                                              "for the f0 that sounds there with this bow (instead of --f0).")


A4Opt = typer.Option(None, "--a4", help="Tuning of --pitch note names: A4 in Hz (default 440).")


def scene_from_flags(preset, f0, fb, vb, a, duration, sample_rate, q0, p0, pitch=None, a4=None, ratio=None):
    from ..controls import parse_control
    from ..music.request import make_scene

    fb = None if fb is None else parse_control(fb, "fb")
    vb = None if vb is None else parse_control(vb, "vb")
    return make_scene(preset, f0=f0, fb=fb, vb=vb, a=a, duration=duration, sample_rate=sample_rate, q0=q0, p0=p0,
                      pitch=pitch, a4=a4, ratio=ratio)


def pitch_hz(pitch, a4) -> float:
    from ..music.notes import A4_HZ, parse_pitch

    return parse_pitch(pitch, A4_HZ if a4 is None else a4)


def process_seconds() -> float | None:
    """Wall seconds since this process started (the interpreter's start-up and imports included), from the kernel's
    accounting (Linux /proc); None where that is not available."""
    import os

    try:
        with open("/proc/self/stat", "rb") as f:
            start_ticks = int(f.read().rsplit(b")", 1)[1].split()[19])
        with open("/proc/uptime", "rb") as f:
            uptime = float(f.read().split()[0])
        return max(uptime - start_ticks / os.sysconf("SC_CLK_TCK"), 0.0)
    except (OSError, ValueError, IndexError):
        return None


def tell(quiet: bool, msg: str, console: Console | None = None) -> None:
    if not quiet:
        (console or out).print(msg, soft_wrap=True)


@app.callback()
def _main(debug: bool = typer.Option(False, "--debug", help="Show full tracebacks on errors.")):
    run_state["debug"] = debug


ForceOpt = typer.Option(False, "--force", help="Replace a read-only output file; run work estimated past "
                                                 "minutes or gigabytes.")


DcOpt = typer.Option("remove", "--dc", help="remove (default): high-pass the written signal at 5 Hz (the bow's static "
                                            "offset is not sound); keep: write it as rendered.")


WINDOWS_HELP = ("Operator: free: windows of the trained length (the network's error spreads into faint lines between "
                "and below the harmonics, about 60 dB down); locked: a held bow's windows divide the period the "
                "model sounds, so the error lands on its harmonics instead (truer chords and mixes; ~1.7-2x the "
                "work); physics: they divide the physics' period at the bow, which pulls the note onto the physical "
                "pitch over its first tens of periods where the model holds it (the truest pitch at a given f0); "
                "auto: per model, bow and pitch free or physics windows (in the fewest that hold the lock or up "
                "to three more a period), whichever sounds truest against the FDM (harmonics' dB and cents, "
                "measured once per model and bow and cached; docs/BENCHMARKS.md).")
# None: the default of each (music.engine_tuning's RENDER_WINDOWS, SCORE_WINDOWS, LIVE_WINDOWS)
WindowsOpt = typer.Option(None, "--windows", help=WINDOWS_HELP + " Default: auto (a first render of a bow measures "
                                                                 "its choice, 0.5-3 s; later ones read the cache).")
ScoreWindowsOpt = typer.Option(None, "--windows", help=WINDOWS_HELP + " Default for a score: locked.")
LiveWindowsOpt = typer.Option(None, "--windows", help=WINDOWS_HELP + " Default live: free.")


GainOpt = typer.Option(None, "--gain", help="Fixed gain in dB instead of peak normalisation: samples = signal (m or "
                                            "m/s; a mix: the sum of the notes' q = w u, or of p) x 10^(DB/20); "
                                            "refused if it would clip.")


def console_for(output) -> Console:
    """Where messages go: stderr when the audio itself goes to stdout."""
    return err if str(output) == "-" else out


def fmt_num(v, fmt: str) -> str:
    return num(v, fmt)


def resting_grid_text(v: dict) -> str | None:
    """What a validation record whose grid bows all damp the mass says (a model of the heavy bows' stops, halt-edge),
    or None for any other: it has no pitch or NMSE, only whether the model rests where the truth does."""
    if v.get("speaking") == 0 and v.get("resting") is not None and v.get("silent_sounding") is not None:
        try:
            return (f"the bow damps the mass at every grid bow, where the truth rests; the model rests at "
                    f"{fmt_num(v['resting'] - v['silent_sounding'], 'g')} of {fmt_num(v['resting'], 'g')}")
        except TypeError:  # not numbers: a record edited by hand
            return None
    return None


def range_validation_text(v: dict, whose: str = "the") -> str:
    """A range model's validation record (training.validate_range) as train and render state it."""
    # numbers only: the record comes from a file, and its text would reach the terminal (and rich's markup)
    g, secs, ref = fmt_num(v.get("grid"), "g"), fmt_num(v.get("seconds"), "g"), fmt_num(v.get("ref_oversample"), "g")
    rests = resting_grid_text(v)
    if rests:
        return f"validation ({secs} s from rest on a {g} x {g} grid of {whose} box vs FDM x{ref}): {rests}"
    return (f"validation ({secs} s from rest on a {g} x {g} grid of {whose} box vs FDM "
            f"x{ref}, where the note speaks): harmonics "
            f"{fmt_num(v.get('harm_db_median'), '.2g')} dB median, pitch {fmt_num(v.get('cents_abs_max'), '.2g')} cents "
            f"worst; median NMSE(p) {fmt_num(v.get('nmse'), '.3g')}, worst {fmt_num(v.get('nmse_max'), '.3g')}")
