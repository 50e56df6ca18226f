"""`bowsynth score`: a TOML score, a MIDI file or a list of presets rendered to a mix and/or stems."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from ..errors import UsageError
from .app import DcOpt, DurOpt, ForceOpt, GainOpt, ScoreWindowsOpt, app, console_for, tell


@app.command()
def score(
    output: Path = typer.Argument(..., help="A directory (one WAV per note, and notes.json) or, with --mix, an "
                                            "audio file (.wav, .flac, .ogg, or - for WAV on standard output)."),
    score_file: Optional[Path] = typer.Option(None, "--score", help="A TOML score (docs/score.md) or a MIDI file (.mid)."),
    presets_list: Optional[str] = typer.Option(None, "--presets", help="Comma-separated preset names, one voice each."),
    duration: Optional[float] = DurOpt,
    method: str = typer.Option("operator", "--method", "-m", help="operator (one batched rollout) or fdm (one by one)."),
    model: Optional[Path] = typer.Option(None, "--model", help="Operator model: a file or a model's name, as in render "
                                                               "(default: the one covering each note)."),
    mix: bool = typer.Option(False, "--mix", help="Write one mixed file (each note at its start) instead of one file per note."),
    stems: Optional[Path] = typer.Option(None, "--stems", help="With --mix: also write one WAV per note into this "
                                                                "directory (what `compare` on the mix reads)."),
    a4: Optional[float] = typer.Option(None, "--a4", help="MIDI files: the tuning of A4 in Hz (default 440)."),
    bend_range: Optional[float] = typer.Option(None, "--bend-range", help="MIDI files: semitones at full pitch "
                                                                          "bend (default 2)."),
    releases: str = typer.Option("auto", "--releases", help="Who plays the bow stops: auto (a model that covers the bow stop, else the FDM) or fdm (the FDM from each hold, as the live engine plays them: to compare with a `play` recording)."),
    fallback: str = typer.Option("none", "--fallback", help="A note no model covers, or that leaves its model's domain: "
                                                            "none (stop before rendering) or fdm (render it with the FDM)."),
    windows: Optional[str] = ScoreWindowsOpt,
    dc: str = DcOpt, gain: Optional[float] = GainOpt, force: bool = ForceOpt,
    quiet: bool = typer.Option(False, "--quiet", "-q", help="Print nothing on success."),
):
    """Play a score: notes in time from a TOML score or a MIDI file (or one voice per preset), in one batched rollout.

    A TOML score has \\[defaults] and \\[\\[voice]] tables; a voice holds \\[\\[voice.note]] tables with start,
    duration (s), pitch ("A4", "C#3", Hz) or f0, fb (m/s^2) or beta (F_B / w), vb, a, release, preset. fb, beta and
    vb take numbers or curves \\[\\[t, value], ...] (t in s from the note's start). A voice without notes is one
    note from 0.
    Each note is tuned to sound at its pitch (at the bow's held values), ends with a bow stop (v_B -> 0 over
    `release` s, default 0.05), and overlaps freely. MIDI: a track's channel is a voice; velocity sets F_B / w and v_B,
    CC2 bow pressure, CC11 expression. Notes no model covers are listed before anything renders. See docs/score.md.
    """
    import time

    from ..engines.limits import check_request
    from ..io.audio import check_audio_output, check_dc, check_gain_db
    from ..io.outfile import check_output_path
    from ..music.mix import check_outputs_fit, stem_paths, write_voices
    from ..music.perform import check_releases, render_notes, same_note
    from ..music.score import load_score, voices_from_presets

    if (score_file is None) == (presets_list is None):
        raise UsageError("give exactly one of --score FILE.toml|FILE.mid or --presets a,b,c")
    from ..engines import Engine, Fallback, parse_choice

    method, fallback = parse_choice(Engine, method, "--method").value, parse_choice(Fallback, fallback, "--fallback").value
    check_releases(releases)  # before the score is read and tuned
    from ..music.engine_tuning import SCORE_WINDOWS, check_windows

    windows = check_windows(windows, SCORE_WINDOWS)
    check_dc(dc)
    check_gain_db(gain)
    if stems is not None and not mix:
        raise UsageError("--stems goes with --mix (without --mix the output directory holds the stems)")
    if score_file is not None:
        if duration is not None:
            raise UsageError("--duration applies to --presets; a score gives each note its duration")
        from ..music.engine_tuning import ratio_for_engine

        # each pitch tuned for the engine that plays it (the FDM's dispersion, the operator model's own ratio)
        if bend_range is not None and not (0 <= bend_range <= 24):
            raise UsageError(f"--bend-range must be 0..24 semitones, got {bend_range:g}")
        from ..engines.operator.choose import available_models

        # the model directories looked at once for every note (a lookup per note was a fifth of a chorale's time)
        pool = available_models() if model is None and str(getattr(method, "value", method)) != "fdm" else None
        def ratio_for(sc):  # the engine's, in the windows it plays
            return ratio_for_engine(sc, method, model, models=pool, windows=windows)[0]
        notes = load_score(score_file, a4=a4, ratio_for=ratio_for, bend_range=bend_range)
    else:
        if a4 is not None:
            raise UsageError("--a4 retunes MIDI files; presets have their own f0")
        notes = voices_from_presets([n.strip() for n in presets_list.split(",") if n.strip()], duration=duration)
    if not notes:
        raise UsageError("no voices to render")
    for line in getattr(notes, "remarks", []):  # what the MIDI reader changed or dropped, counted
        tell(quiet, f"note: {Path(score_file).name}: {line}", console_for(output))
    from ..io.outfile import check_not_input

    check_not_input(output, [score_file], "the output" if mix else "the output directory")
    if mix and stems is not None and "-" not in (str(output), str(stems)):
        check_not_input(stems, [score_file, output], "--stems")
        if Path(output).resolve().parent == Path(stems).resolve() or Path(output).resolve() == Path(stems).resolve():
            raise UsageError(f"--mix {output} and --stems {stems} collide: the mix would be written among the stems "
                             f"(or be the stems' directory); give the mix another place")
    if mix:
        check_audio_output(output, force=force)
    elif str(output) == "-":
        raise UsageError("standard output (-) takes one file: add --mix")
    for d in ([] if mix else [output]) + ([stems] if stems is not None else []):
        if str(d) == "-":
            raise UsageError("--stems needs a directory, not standard output (-)")
        if d.exists() and not d.is_dir():
            raise UsageError(f"{d} is a file; stems go into a directory" + ("" if mix else " (or add --mix)"))
        if not d.exists() and not d.parent.is_dir():
            raise UsageError(f"output directory {d.parent} does not exist")
        if d.is_dir():
            for path in stem_paths(notes, d):
                check_output_path(path, force=force)
    check_outputs_fit(notes, output if mix else None, stems if mix else output, dc=dc)
    check_request([n.scene for n in notes], method, 1, force, extra_voices=int(mix))
    if mix:
        from ..engines.limits import check_mix

        check_mix([n.start for n in notes], [n.scene for n in notes], force)
    t0 = time.perf_counter()
    renders = render_notes(notes, method=method, model=model, fallback=fallback, source=score_file, releases=releases,
                           windows=windows)
    secs = time.perf_counter() - t0
    say = console_for(output)
    # a remark that holds for many notes (a model's physics check, say) is said once, with how many notes it concerns
    said: dict[str, list[str]] = {}
    for n, r in zip(notes, renders):
        for line in r.info.notes:
            said.setdefault(line, []).append(n.describe())
    for line, who in said.items():
        where = who[0] if len(who) == 1 else f"{who[0]} and {len(who) - 1} more notes"
        tell(quiet, f"{where}: {line}", say)
    paths = write_voices(notes, renders, output, mix=mix, stems=stems, dc=dc, gain_db=gain, force=force)
    audio = sum(n.scene.duration for n in notes)
    voices = len({n.name for n in notes})
    used = sorted({f"{r.info.model_id} ({r.info.model_path})" for r in renders if r.info.model_path}
                  | {r.info.release_model for r in renders if r.info.release_model}
                  | {" -> ".join(name for _, name in r.info.chain) for r in renders if r.info.chain})
    by = [r.info.release for r in renders if r.info.release]
    stops = (f"; bow stops: {by.count('operator')} by the operator, {by.count('fdm')} by the FDM"
             if method == "operator" and by else "")
    shown = ", ".join(str(p) for p in paths[:4]) + (f" and {len(paths) - 4} more" if len(paths) > 4 else "")
    distinct = len({same_note(n) for n in notes})  # a repeat is a copy of its first (render_notes)
    again = f" ({distinct} distinct)" if distinct < len(notes) else ""
    tell(quiet, f"rendered {len(notes)} notes{again} in {voices} voices ({audio:g} s of audio) with {method} in {secs:.3f} s "
                f"({audio / max(secs, 1e-9):.0f}x real time in all)" + (f", model {', '.join(used)}" if used else "")
                + stops + f"; wrote {shown}", say)
