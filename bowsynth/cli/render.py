"""`bowsynth render`: one scene to an audio file, by the operator or the FDM."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from ..errors import UsageError
from .app import (
    A4Opt,
    AOpt,
    DcOpt,
    DurOpt,
    F0Opt,
    FbOpt,
    ForceOpt,
    GainOpt,
    P0Opt,
    PitchOpt,
    PresetOpt,
    Q0Opt,
    RateOpt,
    VbOpt,
    WindowsOpt,
    app,
    console_for,
    err,
    pitch_hz,
    process_seconds,
    range_validation_text,
    scene_from_flags,
    tell,
)


@app.command()
def render(
    output: Path = typer.Argument(..., help="Audio file to write: .wav (32-bit float), .flac (24-bit), .ogg "
                                            "(Vorbis), or - for WAV on standard output."),
    method: str = typer.Option("operator", "--method", "-m", help="Engine: operator (trained PI-DeepONet) or fdm."),
    preset: Optional[str] = PresetOpt, f0: Optional[float] = F0Opt, fb: Optional[str] = FbOpt,
    vb: Optional[str] = VbOpt, a: Optional[float] = AOpt, duration: Optional[float] = DurOpt,
    sample_rate: Optional[int] = RateOpt, q0: Optional[float] = Q0Opt, p0: Optional[float] = P0Opt,
    pitch: Optional[str] = PitchOpt, a4: Optional[float] = A4Opt,
    oversample: int = typer.Option(1, "--oversample", help="FDM only: render at this multiple of the sample rate."),
    model: Optional[Path] = typer.Option(None, "--model", help="Operator model: a file, or a name in ./models or the "
                                                               "shipped models (soft-range; `bowsynth models` lists "
                                                               "them). Default: the model covering the scene."),
    signal: str = typer.Option("u", "--signal", help="Signal to write: u (displacement, as the paper) or p (velocity)."),
    fallback: str = typer.Option("none", "--fallback", help="If the operator leaves its domain: none (stop) or fdm."),
    windows: Optional[str] = WindowsOpt,
    dc: str = DcOpt, gain: Optional[float] = GainOpt, force: bool = ForceOpt,
    quiet: bool = typer.Option(False, "--quiet", "-q", help="Print nothing on success."),
):
    """Render a scene to an audio file (WAV, FLAC, OGG, or - for stdout)."""
    from .. import api
    from ..engines import Engine, Fallback, parse_choice
    from ..io.audio import check_audio_output, check_dc, check_gain_db, check_meta_fits, render_meta, write_wav
    from ..music.engine_tuning import check_windows

    method, fallback = parse_choice(Engine, method, "--method").value, parse_choice(Fallback, fallback, "--fallback").value

    if signal not in ("u", "p"):
        raise UsageError(f"--signal must be u or p, got {signal!r}")
    if oversample < 1:
        raise UsageError(f"--oversample must be >= 1, got {oversample}")
    check_dc(dc)
    check_gain_db(gain)
    windows = check_windows(windows)
    scene = scene_from_flags(preset, f0, fb, vb, a, duration, sample_rate, q0, p0, pitch, a4)
    check_audio_output(output, force=force)
    check_meta_fits(render_meta(scene, "operator fallback fdm", signal, 1.0, 0.0, "x" * 64, dc), output)
    if pitch is not None:  # tuned again with the sounding ratio of the engine that plays (its own pitch)
        from ..music.notes import note_name

        ratio, by = api.tuning_for(scene, method, model, oversample, windows=windows)
        scene = scene_from_flags(preset, f0, fb, vb, a, duration, sample_rate, q0, p0, pitch, a4, ratio=ratio)
        hz = pitch_hz(pitch, a4)
        held = "" if not scene.varying else ", at the values the bow holds"
        how = f"tuned for {by}"
        tell(quiet, f"pitch {hz:.2f} Hz ({note_name(hz, a4 or 440.0)}): f0 {scene.f0:.4f} Hz ({how}{held})",
             console_for(output))
    r = api.render(scene, engine=method, model=model, fallback=fallback, oversample=oversample, force=force,
                   windows=windows)
    write_wav(output, r, signal=signal, dc=dc, gain_db=gain, force=force)
    model_note = f", model {r.info.model_id}" if r.info.model_id else ""
    if r.info.chain:  # models in turn: their names (the note below says when each took over)
        model_note = f", models {' -> '.join(name for _, name in r.info.chain)}"
    elif r.info.model_path:
        model_note += f" ({r.info.model_path})"
    setup = r.info.setup_seconds
    setup_note = f" after {setup * 1e3:.0f} ms of start-up" if setup else ""
    whole = process_seconds()
    if whole is not None:  # what the user waited for: the interpreter, imports, tuning, model loads and the render
        setup_note += f"; the whole command {whole:.2f} s so far"
    say = console_for(output)
    if not quiet:
        if r.info.windows:
            to = "the note" if windows == "locked" else "the physics' period"  # physics, or auto's lock
            model_note += f", windows locked to {to} ({r.info.windows} a period)"
        say.print(f"wrote {'standard output' if str(output) == '-' else output}: {scene.duration:g} s at "
                  f"{scene.sample_rate} Hz, method {r.method}{model_note}; rendered in {r.seconds * 1e3:.1f} ms "
                  f"({r.realtime_factor:.0f}x real time){setup_note}", soft_wrap=True)
        for note in r.info.notes:
            say.print(note, soft_wrap=True)
        rv = r.info.range_validation
        if rv and (rv.get("nmse") is not None or rv.get("speaking") == 0):
            say.print(f"note: a range model; its {range_validation_text(rv, 'its')}; `bowsynth compare "
                      f"{output if str(output) != '-' else 'FILE'}` measures this render", soft_wrap=True)
