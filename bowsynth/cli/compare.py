"""`bowsynth compare`: a rendered file against the FDM at 100x its sample rate, in numbers, a plot or a report."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from ..errors import UsageError
from .app import AOpt, F0Opt, FbOpt, P0Opt, PresetOpt, Q0Opt, VbOpt, app, console_for, out, scene_from_flags


@app.command()
def compare(
    wav: Path = typer.Argument(..., help="A WAV written by `bowsynth render` (or any mono WAV, with scene flags)."),
    other: Optional[Path] = typer.Argument(None, help="A second WAV: compare the two directly instead of with the FDM."),
    reference: str = typer.Option("high", "--reference", help="high (default): a x100 FDM, the truth, with the audio-rate FDM beside; audio: the audio-rate FDM only (fast)."),
    json_out: bool = typer.Option(False, "--json", help="Print the metrics as JSON."),
    plot: Optional[Path] = typer.Option(None, "--plot", help="Write waveform, error and spectrogram plots to this PNG."),
    preset: Optional[str] = PresetOpt, f0: Optional[float] = F0Opt, fb: Optional[str] = FbOpt,
    vb: Optional[str] = VbOpt, a: Optional[float] = AOpt, q0: Optional[float] = Q0Opt, p0: Optional[float] = P0Opt,
    force: bool = typer.Option(False, "--force", help="Replace a read-only --plot file; run FDM references "
                                                     "estimated past a couple of minutes."),
    report: Optional[Path] = typer.Option(None, "--report", help="Also write a self-contained HTML listening report (players, harmonics, pitch, onset, spectrograms, metrics) to this file."),
    report_notes: int = typer.Option(8, "--report-notes", help="A mix's --report: a section for each of its N worst notes (by NMSE)."),
):
    """Compare a render against the FDM: NMSE, NCC, pitch (cents), harmonics, spectrum, and speed."""
    import json

    from ..analysis.compare import compare_wav, format_table, plot_comparison
    from ..io.audio import check_output_path, read_wav

    if reference not in ("audio", "high"):
        raise UsageError(f"--reference must be audio or high, got {reference!r}")
    from ..io.outfile import check_not_input

    for flag, target in (("--plot", plot), ("--report", report)):
        check_not_input(target, [wav, other], flag)
    if plot is not None and report is not None:
        check_not_input(report, [plot], "--report")
    if plot is not None:
        check_output_path(plot, force=force)
        if plot.suffix.lower() != ".png" and str(plot) != "-":
            raise UsageError(f"--plot writes a PNG; give a .png file name, got {plot}")
    if report is not None:
        from ..report.compare_page import check_report_path

        check_report_path(report, plot, report_notes, force)
    scene = None
    info = read_wav(wav)
    from ..analysis.compare import compare_mix, format_mix_table, mix_meta

    if info.meta is None and other is None and mix_meta(wav) is not None:
        if plot is not None:
            raise UsageError("--plot draws one note; give a stem of the mix (its stems directory has one per note)")
        rows = compare_mix(wav, reference=reference, force=force)
        if json_out:
            out.print_json(json.dumps([{"note": n, **c.to_json()} for n, c in rows]))
        else:
            out.print(format_mix_table(rows))
        if report is not None:
            from ..report.compare_page import write_mix_report

            write_mix_report(report, wav, rows, worst=report_notes, force=force)
            if not json_out:
                out.print(f"report written to {report}")
        return
    if info.meta is not None and other is None and any(v is not None for v in (preset, f0, fb, vb, a, q0, p0)):
        raise UsageError(f"{wav} carries its scene in its metadata; the scene flags are for files without it")
    if info.meta is None and other is None:
        if all(v is None for v in (preset, f0, fb, vb, a)):
            raise UsageError(f"{wav} has no bowsynth metadata; give the scene with --fb/--vb/--f0/... flags")
        scene = scene_from_flags(preset, f0, fb, vb, a, len(info.samples) / info.sample_rate, info.sample_rate, q0, p0)
    c = compare_wav(wav, other, scene=scene, reference=reference, force=force)
    say = console_for(plot)  # a plot on stdout sends the table to stderr
    if json_out:
        say.print_json(json.dumps(c.to_json()))
    else:
        say.print(format_table(c))
        for note in c.notes:
            say.print(f"note: {note}", soft_wrap=True)
    if plot is not None:
        plot_comparison(c, plot, info.sample_rate)
        if not json_out:
            say.print(f"plot written to {'standard output' if str(plot) == '-' else plot}")
    if report is not None:
        from ..report.compare_page import write_compare_report

        write_compare_report(report, c, info, force=force)
        if not json_out:
            say.print(f"report written to {report}")
