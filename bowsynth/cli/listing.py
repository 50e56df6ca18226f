"""`bowsynth presets` and `bowsynth models`: what can be played, and by which trained operators."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from .app import app, err, fmt_num, out, resting_grid_text


@app.command()
def presets():
    """List the preset scenes, the pitch each sounds at, and the model that plays it (or how to get one)."""
    from rich.markup import escape

    from ..engines.operator.choose import available_models, find_model, train_hint
    from ..errors import DomainError
    from ..music.notes import note_name
    from ..music.request import make_scene
    from ..music.tuning import sounding_pitch
    from ..scene import list_presets, load_preset, preset_description

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


@app.command()
def models(
    report: Optional[Path] = typer.Option(None, "--report", help="Also write an HTML report: each model's metadata, a map of its error over its box at held-out bows, players. Renders against a x100 FDM: tens of seconds."),
    report_grid: int = typer.Option(3, "--report-grid", help="--report: held-out bows per side of a range model's box (N x N FDM runs)."),
    force: bool = typer.Option(False, "--force", help="Replace a read-only --report file."),
    only: Optional[str] = typer.Option(None, "--only", help="These models only, by name (comma-separated, e.g. soft-range,stick-heavy): listed and, with --report, reported (a report of every model renders for about a minute)."),
    long: bool = typer.Option(False, "--long", "-l", help="Each model in full: its id, box in F_B, window, validation record and training time."),
    map_png: Optional[Path] = typer.Option(None, "--map", help="Also draw the tiling of the bow plane (F_B / w x v_B) to this PNG: each model's box, failed ones hatched."),
):
    """List the operator models found in ./models and the shipped ones: a table of where each plays, how accurate its
    validation was, and its size (--long: in full)."""
    from rich.markup import escape

    from ..engines.operator.choose import scan_models
    from ..engines.operator.modelfile import unpicked_text

    if report is not None:
        from ..report.models_page import check_report_path

        check_report_path(report, report_grid, force)
    if map_png is not None:
        from ..io.outfile import check_output_path
        from ..errors import UsageError

        if map_png.suffix.lower() != ".png":
            raise UsageError(f"--map draws a PNG; give a .png file name, got {map_png}")
        check_output_path(map_png, force=force)
    found = _only(scan_models(), only)
    if not found:
        out.print("no models found (train one with `bowsynth train --fb 100`)")
    for recipe, why in _recipe_problems(found):
        out.print(f"[bold]{escape(str(recipe.with_suffix('.safetensors')))}[/bold]  {escape(why.upper() if why == 'missing' else why)}: "
                  f"`make models` (or `bowsynth train --config {escape(str(recipe))} --update`) trains it",
                  soft_wrap=True)
    if not long:
        _table(found)
    for path, m, why in found if long else []:
        if m is None:
            out.print(f"[bold]{escape(str(path))}[/bold]  UNREADABLE: {escape(why)}", soft_wrap=True)
            continue
        d, v = m.domain, m.meta.validation
        sc = m.meta.scene
        mark = f"  FAILED ({escape(m.failure)}): {unpicked_text(m.meta)}" if m.failure else ""
        fmt = "" if m.meta.format_version >= 2 else " (format 1: no digest; checked by its physics at render time)"
        if d.is_range:
            b0, b1, v0, v1 = d.box
            from .. import physics  # numpy: not for every command's start (`--help` took 0.13 s longer)

            w = physics.omega(sc["f0"])
            heard = resting_grid_text(v) or (
                f"harmonics {fmt_num(v.get('harm_db_median'), '.2g')} dB median, pitch "
                f"{fmt_num(v.get('cents_abs_max'), '.2g')} cents worst, median NMSE(p) {fmt_num(v.get('nmse'), '.3g')}, "
                f"worst {fmt_num(v.get('nmse_max'), '.3g')}")
            what = (f"range model: F_B/w {b0:.4g}..{b1:.4g} (F_B {b0 * w:.4g}..{b1 * w:.4g} at f0 {sc['f0']:g}), "
                    f"vb {v0:g}..{v1:g}, a={d.a:g}, any pitch, follows gestures; window {d.window:.3g} tau; validation "
                    f"{heard}")
        else:
            what = (f"trained for fb={sc['fb']:g} f0={sc['f0']:g} vb={d.vb:g} a={d.a:g} (F_B/w={d.beta:.4g}), window "
                    f"{d.window:.3g} tau; validation NMSE(p) {fmt_num(v.get('nmse'), '.3g')}")
        out.print(f"[bold]{escape(str(m.path))}[/bold]  {m.id}{mark}{fmt}\n    {escape(what)}, "
                  f"{m.meta.training.get('seconds')} s of training", soft_wrap=True)
    if map_png is not None:
        from ..report.atlas import draw_atlas

        draw_atlas([m for _, m, _ in found if m is not None], map_png)
        out.print(f"map written to {map_png}")
    if report is not None:
        from ..report.models_page import write_models_report

        write_models_report(report, found, report_grid, force, progress=lambda s: err.print(s, soft_wrap=True))
        out.print(f"report written to {report}")


def _table(found) -> None:
    """The models at a glance: where each plays (its box of F_B / w and v_B; its windows, a share of the free period
    T), its validation (harmonics dB median / pitch cents worst, or a point model's NMSE), its size."""
    import math

    from rich.markup import escape
    from rich.table import Table

    t = Table(box=None, pad_edge=False, header_style="bold")
    for col in ("model", "window", "F_B / w", "v_B", "validation", "KB"):
        t.add_column(col, justify="right" if col == "KB" else "left", no_wrap=col != "validation")
    for path, m, why in found:
        if m is None:
            t.add_row(escape(path.name), "", "", "", f"UNREADABLE: {escape(why[:70])}", "")
            continue
        d, v = m.domain, m.meta.validation or {}
        share = d.window / (2 * math.pi)
        window = {1.0: "T", 0.5: "T/2", 0.25: "T/4"}.get(round(share, 2), f"{share:.2g} T")
        if d.is_range:
            b0, b1, v0, v1 = d.box
            beta, vb = f"{b0:.3g}-{b1:.3g}", f"{v0:.3g}-{v1:.3g}"
            score = "rests at its grid" if resting_grid_text(v) else (
                f"{fmt_num(v.get('harm_db_median'), '.2g')} dB / {fmt_num(v.get('cents_abs_max'), '.2g')} cents")
        else:
            beta, vb = f"{d.beta:.4g}", f"{d.vb:g}"
            score = f"NMSE {fmt_num(v.get('nmse'), '.2g')}"
        if m.failure:
            score = f"FAILED ({m.failure[:48]})"
        size = f"{path.stat().st_size / 1024:.0f}" if path.exists() else ""
        t.add_row(escape(path.stem), window, beta, vb, escape(score), size)
    from rich.console import Console

    # a pipe or a log (80 columns) reads the rows whole
    Console(file=out.file, width=max(out.width, 112), highlight=False, emoji=False, soft_wrap=False).print(t)


def _only(found: list, only: str | None) -> list:
    """The models named in --only (file stems, in the order found); a name that matches none is a usage error."""
    from ..errors import UsageError

    if only is None:
        return found
    names = [n.strip().removesuffix(".safetensors") for n in only.split(",") if n.strip()]
    stems = [p.stem for p, _, _ in found]
    missing = [n for n in names if n not in stems]
    if not names or missing:
        raise UsageError(f"--only {only}: {'no model named ' + ', '.join(missing) if missing else 'no name given'} "
                         f"(models found: {', '.join(dict.fromkeys(stems)) or 'none'})")
    return [f for f in found if f[0].stem in names]


def _recipe_problems(found) -> list[tuple[Path, str]]:
    """The shipped recipes whose model file is missing or stale (an unreadable one is listed with the files)."""
    from ..engines.operator.choose import SHIPPED_DIR
    from ..errors import BowsynthError
    from .train import recipe_status

    unreadable = {p for p, m, _ in found if m is None}
    problems = []
    for recipe in sorted(SHIPPED_DIR.glob("*.toml")):
        try:
            why = recipe_status(recipe)
        except BowsynthError as e:  # a recipe that no longer parses: said, the listing goes on
            why = f"recipe {recipe.name} unusable: {str(e).splitlines()[0]}"
        if why and recipe.with_suffix(".safetensors") not in unreadable:
            problems.append((recipe, why))
    return problems
