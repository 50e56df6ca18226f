"""A fit as a score (TOML) that `bowsynth score` plays, its numbers in comments: what was fitted, how well the sound
determines it, and the fitted note's sound against the target."""

from __future__ import annotations

from pathlib import Path

from .held import TOLERANCE, Fit, play_windows

PARTS = {"beta": "F_B / w", "vb": "v_B"}


def determined(fit: Fit, part: str) -> str:
    """How well the sound determines a part, in words: 'within +-x %' and whether that meets its tolerance."""
    s = 100 * fit.relative_spread(part)
    ok = "identifiable" if fit.identifiable(part) else f"not identifiable to {100 * TOLERANCE[part]:g} %"
    return f"+-{s:.2g} % ({ok})"


def score_text(fit: Fit, target_name: str, seconds: float) -> str:
    b = fit.best
    lines = [f"# bowsynth fit {target_name}: a held note, {b.f0:.6g} Hz bowed at F_B / w {b.beta:.5g}, v_B {b.vb:.5g}",
             f"# how well the sound determines the bow: F_B / w {determined(fit, 'beta')}, v_B {determined(fit, 'vb')}"]
    for c in fit.alike:
        lines.append(f"# sounds alike: F_B / w {c.beta:.4g}, v_B {c.vb:.4g} (loss {c.loss:.4f}, best {b.loss:.4f})")
    ch = fit.checked
    checked = ch and (f"# the fitted note against the target: harmonics {ch['harmonics_db']:.2f} dB (median), pitch "
                      f"{ch['pitch_cents']:+.2f} cents, onset {ch['onset_ms']:+.1f} ms")
    lines += _closing(checked, fit.interrupted, "bow")
    how = f" --model {b.model} --windows {play_windows(b)}" if b.model else ""
    return _voice(lines, target_name, b.f0, f"{fit.fb:.9g}", f"{b.vb:.9g}", seconds, how)


def _closing(checked: str | None, interrupted: bool, what: str) -> list[str]:
    """The comment lines on how the fit sounds against the target, and whether it was interrupted."""
    return ([checked] if checked else []) + (
        [f"# the fit was interrupted: the best {what} found until then"] if interrupted else [])


def _voice(lines: list, target_name: str, f0: float, fb: str, vb: str, seconds: float, how: str = "") -> str:
    """The comment lines, then the score's one voice; `how`: the score command's options that play it as fitted."""
    lines = lines + [f"# play it: bowsynth score --score THIS.toml{how} --mix fitted.wav", "",
                     f"title = {_quote('fitted to ' + target_name)}", "", "[[voice]]", 'name = "fit"',
                     f"f0 = {f0:.9g}", f"fb = {fb}", f"vb = {vb}", f"duration = {seconds:.9g}", ""]
    return "\n".join(lines)


def curves_text(fit, curves, target_name: str, seconds: float) -> str:
    """The score of fitted curves: fb and vb as [[t, value], ...] (F_B in m/s^2 at the curves' f0)."""
    from .. import physics

    w = physics.omega(curves.f0)
    ident = curves.identifiable()
    lines = [f"# bowsynth fit --curves {target_name}: f0 {curves.f0:.6g} Hz, the bow as curves through "
             f"{len(curves.times)} breakpoints",
             f"# breakpoints the sound determines: F_B / w {int(ident[:, 0].sum())} of {len(ident)} (within 2 %), v_B "
             f"{int(ident[:, 1].sum())} of {len(ident)} (within 1 %)"]
    if curves.at_edge:
        lines.append(f"# the curves reach the edge of {curves.model}'s box, the one model the fit rolls: the sound "
                     f"asks for bows past it")
    ch = curves.checked
    checked = ch and (f"# the fitted curves against the target per 100 ms frame: harmonics {ch['harmonics_db']:.2f} "
                      f"dB (median; worst frame {ch['harmonics_db_worst']:.2f}), pitch {ch['pitch_cents']:.2f} cents")
    lines += _closing(checked, curves.interrupted, "curves")
    pts = lambda v, scale=1.0: "[" + ", ".join(f"[{t:.6g}, {x * scale:.9g}]" for t, x in zip(curves.times, v)) + "]"  # noqa: E731
    return _voice(lines, target_name, curves.f0, pts(curves.beta, w), pts(curves.vb),
                  max(seconds, float(curves.times[-1])))


def _quote(s: str) -> str:
    import json

    return json.dumps(s)  # a TOML basic string is a JSON string for the characters a file name holds


def write_score(fit: Fit, path, target_name: str, seconds: float, force: bool = False, curves=None) -> Path:
    from ..io.outfile import atomic_write

    text = score_text(fit, target_name, seconds) if curves is None else curves_text(fit, curves, target_name, seconds)
    text = text.replace("THIS.toml", Path(str(path)).name)

    def write(tmp):
        Path(tmp).write_text(text, encoding="utf-8")
    atomic_write(path, write, force=force)
    return Path(path)
