"""Command-line interface: a thin layer over the Python API. Errors print as one line; --debug shows tracebacks."""

from __future__ import annotations

import os
import signal
import sys
import warnings
from pathlib import Path
from typing import Optional

import typer
from typer.exceptions import Abort, Exit, TyperException
from rich.console import Console

from .errors import BowsynthError, Terminated, UsageError, interrupt_exit_code

app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_enable=False,
                  help="bowsynth: a bowed mass-spring synthesizer driven by a physics-informed DeepONet.")
err = Console(stderr=True, highlight=False, emoji=False)  # ":100:" in a message is text, not an emoji
out = Console(highlight=False, emoji=False)
_state = {"debug": False, "signal": None}

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


def _scene(preset, f0, fb, vb, a, duration, sample_rate, q0, p0, pitch=None, a4=None, ratio=None):
    from .controls import parse_control
    from .scene import make_scene

    fb = None if fb is None else parse_control(fb, "fb")
    vb = None if vb is None else parse_control(vb, "vb")
    return make_scene(preset, f0=f0, fb=fb, vb=vb, a=a, duration=duration, sample_rate=sample_rate, q0=q0, p0=p0,
                      pitch=pitch, a4=a4, ratio=ratio)


def _pitch_hz(pitch, a4) -> float:
    from .pitch import A4_HZ, parse_pitch

    return parse_pitch(pitch, A4_HZ if a4 is None else a4)


def _say(quiet: bool, msg: str, console: Console | None = None) -> None:
    if not quiet:
        (console or out).print(msg, soft_wrap=True)


@app.callback()
def _main(debug: bool = typer.Option(False, "--debug", help="Show full tracebacks on errors.")):
    _state["debug"] = debug


@app.command()
def presets():
    """List the preset scenes, the pitch each sounds at, and the model that plays it (or how to get one)."""
    from .errors import DomainError
    from .pitch import note_name, sounding_pitch
    from .rollout import available_models, find_model, train_hint
    from .scene import list_presets, load_preset, make_scene, preset_description
    from rich.markup import escape

    models = available_models()
    for name in list_presets():
        fields = " ".join(f"{k}={v:g}" if isinstance(v, (int, float)) else f"{k}={v}"
                          for k, v in load_preset(name).items())
        sc = make_scene(name)
        if sc.varying:
            heard = "its pitch when the bow holds its median values"
        else:
            hz = sounding_pitch(sc.f0, sc.fb, sc.vb, sc.a)
            heard = f"{hz:.2f} Hz ({note_name(hz)})"
        try:
            m = find_model(sc, models)
            who = m.path.name if m.path else m.meta.name
        except DomainError:
            who = f"none: FDM only, train with `{train_hint(sc)}`"
        out.print(f"[bold]{name}[/bold]  {escape(fields)}\n    {escape(preset_description(name))}\n    f0 {sc.f0:.4g} Hz "
                  f"sounds at {heard}; model: {escape(who)}", soft_wrap=True)


ForceOpt = typer.Option(False, "--force", help="Replace a read-only output file; run work estimated past "
                                                 "minutes or gigabytes.")
DcOpt = typer.Option("remove", "--dc", help="remove (default): high-pass the written signal at 5 Hz (the bow's static "
                                            "offset is not sound); keep: write it as rendered.")
GainOpt = typer.Option(None, "--gain", help="Fixed gain in dB instead of peak normalisation: samples = signal (m or "
                                            "m/s; a mix: the sum of the notes' q = w u, or of p) x 10^(DB/20); "
                                            "refused if it would clip.")


def _speaker(output) -> Console:
    """Where messages go: stderr when the audio itself goes to stdout."""
    return err if str(output) == "-" else out


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
    dc: str = DcOpt, gain: Optional[float] = GainOpt, force: bool = ForceOpt,
    quiet: bool = typer.Option(False, "--quiet", "-q", help="Print nothing on success."),
):
    """Render a scene to an audio file (WAV, FLAC, OGG, or - for stdout)."""
    from . import api
    from .engines import Engine, Fallback, parse_choice
    from .wav import check_audio_output, check_dc, check_gain_db, check_meta_fits, render_meta, write_wav

    method, fallback = parse_choice(Engine, method, "--method").value, parse_choice(Fallback, fallback, "--fallback").value

    if signal not in ("u", "p"):
        raise UsageError(f"--signal must be u or p, got {signal!r}")
    if oversample < 1:
        raise UsageError(f"--oversample must be >= 1, got {oversample}")
    check_dc(dc)
    check_gain_db(gain)
    scene = _scene(preset, f0, fb, vb, a, duration, sample_rate, q0, p0, pitch, a4)
    check_audio_output(output, force=force)
    check_meta_fits(render_meta(scene, "operator fallback fdm", signal, 1.0, 0.0, "x" * 64, dc), output)
    if pitch is not None:  # tuned again with the sounding ratio of the engine that plays (its own pitch)
        from .pitch import note_name

        ratio, by = api.tuning_for(scene, method, model, oversample)
        if ratio is not None:
            scene = _scene(preset, f0, fb, vb, a, duration, sample_rate, q0, p0, pitch, a4, ratio=ratio)
        hz = _pitch_hz(pitch, a4)
        held = "" if not scene.varying else ", at the values the bow holds"
        how = f"tuned for {by}" if ratio is not None else f"tuned with the FDM's ratio: {by}"
        _say(quiet, f"pitch {hz:.2f} Hz ({note_name(hz, a4 or 440.0)}): f0 {scene.f0:.4f} Hz ({how}{held})",
             _speaker(output))
    r = api.render(scene, engine=method, model=model, fallback=fallback, oversample=oversample, force=force)
    write_wav(output, r, signal=signal, dc=dc, gain_db=gain, force=force)
    model_note = f", model {r.info['model_id']}" if r.info.get("model_id") else ""
    if r.info.get("model_path"):
        model_note += f" ({r.info['model_path']})"
    setup = r.info.get("setup_seconds")
    setup_note = f" after {setup * 1e3:.0f} ms of start-up" if setup else ""
    say = _speaker(output)
    if not quiet:
        say.print(f"wrote {'standard output' if str(output) == '-' else output}: {scene.duration:g} s at "
                  f"{scene.sample_rate} Hz, method {r.method}{model_note}; rendered in {r.seconds * 1e3:.1f} ms "
                  f"({r.realtime_factor:.0f}x real time){setup_note}", soft_wrap=True)
        for note in r.info.get("notes", []):
            say.print(note, soft_wrap=True)
        rv = r.info.get("range_validation")
        if rv and rv.get("nmse") is not None:
            say.print(f"note: a range model; its validation (1 s from rest on a {rv.get('grid')} x {rv.get('grid')} "
                      f"grid of its box vs FDM x100): median NMSE(p) {rv['nmse']:.2g}, worst "
                      f"{_num(rv.get('nmse_max'), '.2g')}; `bowsynth compare "
                      f"{output if str(output) != '-' else 'FILE'}` measures this render",
                      soft_wrap=True)


@app.command()
def train(
    preset: Optional[str] = PresetOpt, f0: Optional[float] = F0Opt, fb: Optional[str] = FbOpt,
    vb: Optional[str] = VbOpt, a: Optional[float] = AOpt,
    q0: Optional[float] = Q0Opt, p0: Optional[float] = P0Opt,
    minutes: Optional[float] = typer.Option(None, "--minutes", help="Wall-clock budget in minutes (default 5 when --steps is not given; at most a day)."),
    steps: Optional[int] = typer.Option(None, "--steps", help="Optimiser steps (with --minutes, whichever ends first)."),
    seed: Optional[int] = typer.Option(None, "--seed", help="Random seed (default 0): same seed and machine, same model (with --steps)."),
    optimizer: Optional[str] = typer.Option(None, "--optimizer", help="soap (pytorch-optimizer's SOAP, default) or adam."),
    lbfgs: Optional[float] = typer.Option(None, "--lbfgs", help="Share of the --minutes budget for an L-BFGS finish (0 to 0.9, default 0)."),
    hybrid: bool = typer.Option(True, "--hybrid/--no-hybrid", help="Add the FDM data loss (default) or train purely physics-informed."),
    window_ms: Optional[float] = typer.Option(None, "--window-ms", help="Window length in ms at the scene's f0 (default: one period of the free oscillator)."),
    width: Optional[int] = typer.Option(None, "--width", help="Hidden width of branch and trunk (default 64)."),
    depth: Optional[int] = typer.Option(None, "--depth", help="Hidden layers of branch and trunk (default 4)."),
    rest_linear: bool = typer.Option(False, "--rest-linear", help="Point models whose note starts slowly (v_B near 0.3): carry the bowed mass's flow linearised at its rest state, so the onset's growth rate is exact (docs/BENCHMARKS.md)."),
    from_model: Optional[str] = typer.Option(None, "--from", help="Refine a trained range model (a file, or a name such as soft-range) for these bows or this score: its network is kept and trained further on their data only (the bows must lie in its box)."),
    n_data: Optional[int] = typer.Option(None, "--n-data", help="FDM training trajectories (hybrid) drawn from the scene's band (default 4096)."),
    checkpoint_every: Optional[float] = typer.Option(None, "--checkpoint-every", help="Seconds between checkpoints (default 60)."),
    out_path: Optional[Path] = typer.Option(None, "--out", "-o", help="Model file (default ./models/<name>.safetensors)."),
    force: bool = typer.Option(False, "--force", help="Overwrite an existing model file."),
    resume: bool = typer.Option(False, "--resume", help="Continue from the checkpoint beside --out."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress (a bar in a terminal, a line every 10 s elsewhere)."),
    score: Optional[Path] = typer.Option(None, "--score", help="Train a range model for the bows this score (.toml) or MIDI file (.mid) plays."),
    a4: Optional[float] = typer.Option(None, "--a4", help="With --score: the pitch of A4 in Hz (default 440)."),
):
    """Train a PI-DeepONet for a scene (its F_B / w, v_B, a and the states a render from its initial state visits),
    or for a playing range: --fb LO:HI and/or --vb LO:HI (at --f0), or --score FILE (the bows a score or MIDI file
    plays). A range model plays any bow inside its box and follows gestures through it."""
    from . import api

    box = None
    if score is not None:
        if fb is not None or vb is not None or preset is not None:
            raise UsageError("--score trains for the bows the score plays: drop --fb, --vb and --preset")
        scene, box = _score_box(score, a4)
    elif (fb is not None and ":" in fb) or (vb is not None and ":" in vb):
        scene, box = _range_box(preset, f0, fb, vb, a)
    else:
        scene = _scene(preset, f0, fb, vb, a, None, None, q0, p0)
        if scene.varying:
            raise UsageError("train takes a number or a range LO:HI for --fb and --vb, not a curve (a range model "
                             "follows curves inside its range): e.g. --fb 50:200")
    cfg = api.make_train_config(scene, minutes=minutes, steps=steps, seed=seed, optimizer=optimizer,
                                lbfgs_fraction=lbfgs, hybrid=hybrid, window_ms=window_ms, width=width, depth=depth,
                                n_data=n_data if box is None else None,
                                range_n_data=n_data if box is not None else None,
                                checkpoint_seconds=checkpoint_every, rest_linear=rest_linear or None)
    res = api.train(scene, config=cfg, out=out_path, force=force, resume=resume, progress=not quiet, console=err,
                    box=box, init=from_model)
    v = res.model.meta.validation
    _say(False, f"model written to {res.path} ({res.model.id})")
    if res.model.failure:
        err.print(f"warning: {res.model.failure}: this model is not picked by default (only with --model); train "
                  f"longer (--minutes) before rendering with it", soft_wrap=True)
    if v.get("error"):
        return
    if box is not None:
        _say(False, f"validation (1 s from rest on a {v.get('grid')} x {v.get('grid')} grid of the box vs FDM "
                    f"x{v.get('ref_oversample')}, where the note speaks): median NMSE(p) {_num(v.get('nmse'), '.3g')}, "
                    f"worst {_num(v.get('nmse_max'), '.3g')}")
        return
    _say(False, f"validation (1 s from the scene's initial state vs FDM x{v.get('ref_oversample')}): "
                f"NMSE(p) {_num(v.get('nmse'), '.3g')}, NCC {_num(v.get('ncc_percent'), '.3f')} %, "
                f"pitch error {_num(v.get('cents'), '+.3f')} cents")


def _range_box(preset, f0, fb, vb, a):
    """--fb / --vb as ranges: the ParamBox (beta = F_B / w at --f0) and the scene its band is rendered at."""
    from . import api
    from .training.ranges import ParamBox, parse_range

    base = _scene(preset, f0, None, None, a, None, None, None, None)
    fbr = parse_range(fb, "fb") if fb is not None else (float(base.fb),) * 2
    vbr = parse_range(vb, "vb") if vb is not None else (float(base.vb),) * 2
    for (lo, hi), name in ((fbr, "fb"), (vbr, "vb")):
        if lo < 0:
            raise UsageError(f"--{name} range must be >= 0, got {lo:g}:{hi:g}")
    box = ParamBox.from_forces(fbr, vbr, base.f0, base.a)
    if box.is_point:  # `--fb 100:100` is the point 100
        return base.replace(fb=fbr[0], vb=vbr[0]), None
    return api.range_scene(box, base.f0, base.sample_rate), box


def _score_box(path, a4):
    """--score: the box of bows a score or MIDI file plays (its notes' sustains), at its lowest pitch's f0 (the
    dynamics in tau depend on the bow only; the pitch sets where the windows fall)."""
    from . import api
    from .errors import UsageError as _U
    from .score import load_score as load_notes, score_box
    from .training.ranges import ParamBox

    notes = load_notes(path, a4=a4)
    b = score_box(notes)
    if b["a"][0] != b["a"][1]:
        raise _U(f"{path}: its notes use several friction shapes a ({b['a'][0]:g}..{b['a'][1]:g}); one model "
                 f"covers one a: split the score")
    box = ParamBox(b["beta"][0], b["beta"][1], b["vb"][0], b["vb"][1], b["a"][0])
    return api.range_scene(box, b["f0"][0]), box


def _num(v, fmt: str) -> str:
    return "n/a" if v is None else format(v, fmt)


@app.command()
def models(
    report: Optional[Path] = typer.Option(None, "--report", help="Also write an HTML report: each model's metadata, a map of its error over its box at held-out bows, players. Renders against a x100 FDM: tens of seconds."),
    report_grid: int = typer.Option(3, "--report-grid", help="--report: held-out bows per side of a range model's box (N x N FDM runs)."),
    force: bool = typer.Option(False, "--force", help="Replace a read-only --report file."),
):
    """List the operator models found in ./models and the shipped ones, with their domains and scores."""
    from rich.markup import escape

    from .rollout import scan_models

    if report is not None:
        from .report.models_page import check_report_path

        check_report_path(report, report_grid, force)
    found = scan_models()
    if not found:
        out.print("no models found (train one with `bowsynth train --fb 100`)")
    for path, m, why in found:
        if m is None:
            out.print(f"[bold]{escape(str(path))}[/bold]  UNREADABLE: {escape(why)}", soft_wrap=True)
            continue
        d, v = m.domain, m.meta.validation
        sc = m.meta.scene
        mark = f"  FAILED ({escape(m.failure)}): not picked by default" if m.failure else ""
        fmt = "" if m.meta.format_version >= 2 else " (format 1: no digest; checked by its physics at render time)"
        if d.is_range:
            b0, b1, v0, v1 = d.box
            w = 2 * 3.141592653589793 * sc["f0"]
            what = (f"range model: F_B/w {b0:.4g}..{b1:.4g} (F_B {b0 * w:.4g}..{b1 * w:.4g} at f0 {sc['f0']:g}), "
                    f"vb {v0:g}..{v1:g}, a={d.a:g}, any pitch, follows gestures; window {d.window:.3g} tau; validation "
                    f"median NMSE(p) {_num(v.get('nmse'), '.3g')}, worst {_num(v.get('nmse_max'), '.3g')}")
        else:
            what = (f"trained for fb={sc['fb']:g} f0={sc['f0']:g} vb={d.vb:g} a={d.a:g} (F_B/w={d.beta:.4g}), window "
                    f"{d.window:.3g} tau; validation NMSE(p) {_num(v.get('nmse'), '.3g')}")
        out.print(f"[bold]{escape(str(m.path))}[/bold]  {m.id}{mark}{fmt}\n    {escape(what)}, "
                  f"{m.meta.training.get('seconds')} s of training", soft_wrap=True)
    if report is not None:
        from .report.models_page import write_models_report

        write_models_report(report, found, report_grid, force, progress=lambda s: err.print(s, soft_wrap=True))
        out.print(f"report written to {report}")


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

    from .compare import compare_wav, format_table, plot_comparison
    from .wav import check_output_path, read_wav

    if reference not in ("audio", "high"):
        raise UsageError(f"--reference must be audio or high, got {reference!r}")
    if plot is not None:
        check_output_path(plot, force=force)
        if plot.suffix.lower() != ".png" and str(plot) != "-":
            raise UsageError(f"--plot writes a PNG; give a .png file name, got {plot}")
    if report is not None:
        from .report.compare_page import check_report_path

        check_report_path(report, plot, report_notes, force)
    scene = None
    info = read_wav(wav)
    from .compare import compare_mix, format_mix_table, mix_meta

    if info.meta is None and other is None and mix_meta(wav) is not None:
        if plot is not None:
            raise UsageError("--plot draws one note; give a stem of the mix (its stems directory has one per note)")
        rows = compare_mix(wav, reference=reference, force=force)
        if json_out:
            out.print_json(json.dumps([{"note": n, **c.to_json()} for n, c in rows]))
        else:
            out.print(format_mix_table(rows))
        if report is not None:
            from .report.compare_page import write_mix_report

            write_mix_report(report, wav, rows, worst=report_notes, force=force)
            if not json_out:
                out.print(f"report written to {report}")
        return
    if info.meta is not None and other is None and any(v is not None for v in (preset, f0, fb, vb, a, q0, p0)):
        raise UsageError(f"{wav} carries its scene in its metadata; the scene flags are for files without it")
    if info.meta is None and other is None:
        if all(v is None for v in (preset, f0, fb, vb, a)):
            raise UsageError(f"{wav} has no bowsynth metadata; give the scene with --fb/--vb/--f0/... flags")
        scene = _scene(preset, f0, fb, vb, a, len(info.samples) / info.sample_rate, info.sample_rate, q0, p0)
    c = compare_wav(wav, other, scene=scene, reference=reference, force=force)
    say = _speaker(plot)  # a plot on stdout sends the table to stderr
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
        from .report.compare_page import write_compare_report

        write_compare_report(report, c, info, force=force)
        if not json_out:
            say.print(f"report written to {report}")


@app.command()
def bench(
    what: str = typer.Argument("all", help="What to benchmark: fdm, or all (FDM and operators, speed against error)."),
    quick: bool = typer.Option(False, "--quick", help="A small, fast run."),
    json_out: bool = typer.Option(False, "--json", help="Print JSON instead of Markdown."),
    out_prefix: Optional[Path] = typer.Option(None, "--out", help="Also write PREFIX.md, PREFIX.json and PREFIX.png."),
    anchors: Optional[Path] = typer.Option(None, "--anchors", help="Directory of the paper's rollouts (.npz) to "
                                                                   "score too (default ../shared/anchors if present)."),
    force: bool = typer.Option(False, "--force", help="Replace read-only --out files."),
):
    """Benchmark speed against error: FDM at several rates and each operator, against a high-rate FDM."""
    import json

    from . import bench as B

    if what not in ("fdm", "all"):
        raise UsageError(f"bench target must be fdm or all, got {what!r}")
    if out_prefix is not None:
        from .outfile import check_output_path

        for ext in (".md", ".json", ".png"):
            check_output_path(out_prefix.with_suffix(ext), force=force)
    if what == "fdm":
        rows = B.bench_fdm(quick=quick)
        out.print(json.dumps(rows, indent=2) if json_out else B.fdm_table(rows), soft_wrap=True)
        return
    if anchors is not None and not anchors.is_dir():
        raise UsageError(f"--anchors {anchors} is not a directory")
    res = B.run_all(quick=quick, out_prefix=out_prefix, anchor_dir=anchors or B.DEFAULT_ANCHORS)
    md, js = B.to_markdown(res), json.dumps(B.to_json(res), indent=2)
    if out_prefix is not None:
        from .outfile import atomic_write

        atomic_write(out_prefix.with_suffix(".md"), lambda t: Path(t).write_text(md + "\n"), force=force)
        atomic_write(out_prefix.with_suffix(".json"), lambda t: Path(t).write_text(js + "\n"), force=force)
    out.print(js if json_out else md, soft_wrap=True)


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
    fallback: str = typer.Option("none", "--fallback", help="A note no model covers, or that leaves its model's domain: "
                                                            "none (stop before rendering) or fdm (render it with the FDM)."),
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

    from .limits import check_request
    from .outfile import check_output_path
    from .score import check_outputs_fit, load_score, render_notes, stem_paths, voices_from_presets, write_voices
    from .wav import check_audio_output, check_dc, check_gain_db

    if (score_file is None) == (presets_list is None):
        raise UsageError("give exactly one of --score FILE.toml|FILE.mid or --presets a,b,c")
    from .engines import Engine, Fallback, parse_choice

    method, fallback = parse_choice(Engine, method, "--method").value, parse_choice(Fallback, fallback, "--fallback").value
    check_dc(dc)
    check_gain_db(gain)
    if stems is not None and not mix:
        raise UsageError("--stems goes with --mix (without --mix the output directory holds the stems)")
    if score_file is not None:
        if duration is not None:
            raise UsageError("--duration applies to --presets; a score gives each note its duration")
        if bend_range is not None and not (0 <= bend_range <= 24):
            raise UsageError(f"--bend-range must be 0..24 semitones, got {bend_range:g}")
        notes = load_score(score_file, a4=a4, bend_range=bend_range)
    else:
        if a4 is not None:
            raise UsageError("--a4 retunes MIDI files; presets have their own f0")
        notes = voices_from_presets([n.strip() for n in presets_list.split(",") if n.strip()], duration=duration)
    if not notes:
        raise UsageError("no voices to render")
    for line in getattr(notes, "remarks", []):  # what the MIDI reader changed or dropped, counted
        _say(quiet, f"note: {Path(score_file).name}: {line}", _speaker(output))
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
        from .limits import check_mix

        check_mix([n.start for n in notes], [n.scene for n in notes], force)
    t0 = time.perf_counter()
    renders = render_notes(notes, method=method, model=model, fallback=fallback, source=score_file)
    secs = time.perf_counter() - t0
    say = _speaker(output)
    for n, r in zip(notes, renders):
        for line in r.info.get("notes", []):
            _say(quiet, f"{n.describe()}: {line}", say)
    paths = write_voices(notes, renders, output, mix=mix, stems=stems, dc=dc, gain_db=gain, force=force)
    audio = sum(n.scene.duration for n in notes)
    voices = len({n.name for n in notes})
    used = sorted({f"{r.info['model_id']} ({r.info['model_path']})" for r in renders if r.info.get("model_path")})
    shown = ", ".join(str(p) for p in paths[:4]) + (f" and {len(paths) - 4} more" if len(paths) > 4 else "")
    _say(quiet, f"rendered {len(notes)} notes in {voices} voices ({audio:g} s of audio) with {method} in {secs:.3f} s "
                f"({audio / max(secs, 1e-9):.0f}x real time in all)" + (f", model {', '.join(used)}" if used else "")
                + f"; wrote {shown}", say)


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
):
    """Play live: a JACK client taking MIDI on NAME:midi_in and sounding on NAME:out, until Ctrl-C or SIGTERM.

    Notes, velocities, CC2 (bow pressure) and CC11 (expression) map to the bow exactly as in `score` of a MIDI file,
    and each note is the note `score` would render, placed at its event's frame. Prints a status line (voices,
    callback time against the period, xruns) and a summary at exit. See docs/live.md."""
    from .engines import Engine, parse_choice
    from .live.jack_client import play as run
    from .pitch import A4_HZ

    method = parse_choice(Engine, method, "--method").value
    if voices < 1:
        raise UsageError(f"--voices must be >= 1, got {voices}")
    amp = None if gain is None else 10.0 ** (gain / 20.0)
    run(name=name, server=server, connect=connect or (), voices=voices, engine=method, model=model,
        a4=A4_HZ if a4 is None else a4, amp=amp, bend_range=bend_range)


def _raise_on_signal(signum, frame):
    # raised in the main thread between bytecodes, so `finally` blocks and temp-file cleanup run; a long compiled
    # (numba) call delays it until the call returns (the FDM runs in chunks of well under a second for this)
    _state["signal"] = signum
    raise Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()


def _install_signal_handlers() -> dict:
    """Install the handlers; returns the previous ones (main() restores them, for callers such as tests)."""
    import threading

    _state["signal"] = None
    if threading.current_thread() is not threading.main_thread():
        return {}
    old = {signal.SIGTERM: signal.signal(signal.SIGTERM, _raise_on_signal)}
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:  # not when started with SIGINT ignored
        old[signal.SIGINT] = signal.signal(signal.SIGINT, _raise_on_signal)
    return old


def _exit_interrupted(code: int) -> None:
    err.print("terminated" if code == 143 else "interrupted")
    sys.exit(code)


def main() -> None:
    """Entry point: run the app, turning known failures into one line on stderr and an exit code."""
    old = _install_signal_handlers()
    try:
        _run()
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)


def _run() -> None:
    debug = "--debug" in sys.argv[1:]
    # numpy's OpenBLAS runs the rollout's small products on every core; on a busy 2-core machine each product then
    # waited on the other thread (measured 7-12 ms for a 257x64 by 64x64 product, 0.06-0.1 ms on one thread)
    if "numpy" not in sys.modules:
        os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    warnings.simplefilter("default")
    warnings.filterwarnings("ignore", message=".*torch.jit.script.*")  # raised inside pytorch-optimizer
    warnings.formatwarning = lambda msg, cat, *a, **k: f"warning: {msg}\n"
    try:
        rv = app(standalone_mode=False)
    except BowsynthError as e:
        if debug:
            raise
        err.print(f"error: {e}", soft_wrap=True, markup=False)  # messages quote TOML tables: [[voice]]
        sys.exit(e.exit_code)
    except Abort:
        _exit_interrupted(130)
    except KeyboardInterrupt as e:
        _exit_interrupted(interrupt_exit_code(e))
    except TyperException as e:
        if debug:
            raise
        err.print(f"error: {e.format_message()}", soft_wrap=True)
        sys.exit(2)
    except Exit as e:
        sys.exit(e.exit_code)
    except MemoryError:  # past the estimates (--force): what the machine lacks, exit 1, and no half-written file
        if debug:
            raise
        err.print("error: out of memory: the job is larger than this machine can hold (see the estimate without "
                  "--force)", soft_wrap=True)
        sys.exit(1)
    except Exception as e:  # a bug: still one line unless --debug
        if debug:
            raise
        err.print(f"internal error: {type(e).__name__}: {e} (rerun with --debug for the traceback)", soft_wrap=True)
        sys.exit(1)
    # with standalone_mode=False typer turns a KeyboardInterrupt inside a command into a *returned* 130 (and an
    # explicit Exit into its returned code): without this check Ctrl-C exited 0
    if _state.get("signal") is not None:
        _exit_interrupted(143 if _state["signal"] == signal.SIGTERM else 130)
    if isinstance(rv, int) and rv != 0:
        if rv == 130:
            _exit_interrupted(130)
        sys.exit(rv)
