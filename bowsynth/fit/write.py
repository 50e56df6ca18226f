"""A fit as a score (TOML) that `bowsynth score` plays, its numbers in comments: what was fitted, how well the sound
determines it, and the fitted note's sound against the target."""

from __future__ import annotations

from pathlib import Path

from .held import TOLERANCE, Fit

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
    if ch:
        lines.append(f"# the fitted note against the target: harmonics {ch['harmonics_db']:.2f} dB (median), pitch "
                     f"{ch['pitch_cents']:+.2f} cents, onset {ch['onset_ms']:+.1f} ms")
    if fit.interrupted:
        lines.append("# the fit was interrupted: the best bow found until then")
    lines += [f"# play it: bowsynth score --score THIS.toml --mix fitted.wav", "",
              f"title = {_quote('fitted to ' + target_name)}", "", "[[voice]]", 'name = "fit"',
              f"f0 = {b.f0:.9g}", f"fb = {fit.fb:.9g}", f"vb = {b.vb:.9g}", f"duration = {seconds:.9g}", ""]
    return "\n".join(lines)


def _quote(s: str) -> str:
    import json

    return json.dumps(s)  # a TOML basic string is a JSON string for the characters a file name holds


def write_score(fit: Fit, path, target_name: str, seconds: float, force: bool = False) -> Path:
    from ..io.outfile import atomic_write

    text = score_text(fit, target_name, seconds).replace("THIS.toml", Path(str(path)).name)

    def write(tmp):
        Path(tmp).write_text(text, encoding="utf-8")
    atomic_write(path, write, force=force)
    return Path(path)
