"""The pieces of a self-contained report page: audio as 16-bit WAV data URIs, matplotlib figures as inline SVG, tables,
one stylesheet. Nothing on a page refers to anything outside it, so it opens from disk with no network."""

from __future__ import annotations

import base64
import html
import io
import math
import re
import wave
from pathlib import Path

import numpy as np

from ..io.text import num as text_num

PEAK = 10 ** (-1 / 20)  # -1 dBFS, as the renders are written

CSS = """
body { font: 14px/1.45 system-ui, -apple-system, "Segoe UI", sans-serif; color: #1d2330; background: #f6f7f9;
       margin: 0; }
main { max-width: 1180px; margin: 0 auto; padding: 18px 24px 40px; }
h1 { font-size: 22px; margin: 6px 0 2px; } h2 { font-size: 18px; margin: 26px 0 8px; border-bottom: 1px solid #d5d9e0;
     padding-bottom: 3px; } h3 { font-size: 15px; margin: 16px 0 6px; }
.sub { color: #5a6372; margin: 0 0 10px; } .why { color: #5a6372; font-size: 13px; margin: 2px 0 8px; }
.card { background: #fff; border: 1px solid #dde1e7; border-radius: 6px; padding: 10px 14px; margin: 10px 0; }
.players { display: grid; grid-template-columns: repeat(auto-fill, minmax(255px, 1fr)); gap: 10px; }
.player { background: #fff; border: 1px solid #dde1e7; border-radius: 6px; padding: 8px 10px; }
.player b { display: block; font-size: 13px; } .player span { color: #5a6372; font-size: 12px; display: block;
          min-height: 2.6em; } .player audio { width: 100%; height: 34px; margin-top: 4px; }
table { border-collapse: collapse; font-size: 13px; background: #fff; }
th, td { border: 1px solid #dde1e7; padding: 3px 8px; text-align: left; vertical-align: top; }
td.num { text-align: right; font-variant-numeric: tabular-nums; white-space: nowrap; }
th { background: #eef1f5; font-weight: 600; } td.what { color: #5a6372; font-size: 12px; max-width: 420px; }
.grid2 { display: grid; grid-template-columns: 1fr 1fr; gap: 12px; }
figure.plot { margin: 8px 0; background: #fff; border: 1px solid #dde1e7; border-radius: 6px; padding: 6px; }
figure.plot svg { width: 100%; height: auto; display: block; }
figure.plot figcaption { color: #5a6372; font-size: 12.5px; margin: 4px 4px 2px; }
.kv { display: grid; grid-template-columns: max-content 1fr; gap: 2px 14px; font-size: 13px; }
.kv dt { color: #5a6372; } .kv dd { margin: 0; font-family: ui-monospace, monospace; font-size: 12.5px;
        overflow-wrap: anywhere; }
.bad { color: #b3261e; font-weight: 600; } .note { background: #fff8e1; border-left: 3px solid #e0a800;
       padding: 4px 10px; margin: 6px 0; font-size: 13px; }
nav a { margin-right: 12px; } code { font-size: 12.5px; }
"""


def esc(x) -> str:
    return html.escape(str(x), quote=True)


def num(v, fmt: str) -> str:
    """A number as compare prints it ('n/a' for a missing or non-finite one)."""
    return text_num(v, fmt)


def wav_data_uri(x, sample_rate: int, gain: float) -> str:
    """x x gain as a 16-bit mono PCM WAV data URI (16-bit: a third of float32's size, -96 dB of quantisation, far
    below what a listener compares here). Samples beyond full scale are clipped; callers pick the gain to avoid it."""
    y = np.clip(np.nan_to_num(np.asarray(x, float) * gain), -1.0, 1.0)
    buf = io.BytesIO()
    with wave.open(buf, "wb") as w:
        w.setnchannels(1)
        w.setsampwidth(2)
        w.setframerate(int(sample_rate))
        w.writeframes(np.round(y * 32767).astype("<i2").tobytes())
    return "data:audio/wav;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def common_gain(*signals) -> float:
    """One gain for signals compared by ear: the loudest peaks at -1 dBFS, the others keep their level against it."""
    peak = max((float(np.max(np.abs(s))) for s in signals if len(s)), default=0.0)
    return PEAK / peak if peak > 0 else 1.0


def player(title: str, what: str, x, sample_rate: int, gain: float) -> str:
    dur = len(x) / sample_rate
    return (f'<div class="player"><b>{esc(title)}</b><span>{esc(what)}</span>'
            f'<audio controls preload="metadata" data-seconds="{dur:.6f}" '
            f'src="{wav_data_uri(x, sample_rate, gain)}"></audio></div>')


def difference_player(x, ref, sample_rate: int, gain: float, ref_name: str = "the truth") -> tuple[str, float | None]:
    """A player for x - ref raised by a whole number of dB so that its peak is as loud as the others' (at most +120
    dB); returns its HTML and the boost in dB (None when x equals ref)."""
    d = np.asarray(x, float) - np.asarray(ref, float)
    peak_d = float(np.max(np.abs(d))) if len(d) else 0.0
    if not peak_d > 0:
        return (f'<div class="player"><b>difference</b><span>the file equals {esc(ref_name)} sample for sample: '
                f'nothing to hear</span></div>', None)
    peak = float(np.max(np.abs(x))) or peak_d
    boost = max(0.0, min(120.0, math.floor(20 * math.log10(peak / peak_d))))
    what = (f"file - {ref_name}, raised by +{boost:.0f} dB (at the others' level it would be {boost:.0f} dB "
            f"quieter than this)")
    return player("difference, scaled up", what, d, sample_rate, gain * 10 ** (boost / 20)), boost


def svg(fig) -> str:
    """A matplotlib figure as an inline <svg> element (closes the figure)."""
    import matplotlib.pyplot as plt

    buf = io.StringIO()
    fig.savefig(buf, format="svg", bbox_inches="tight")
    plt.close(fig)
    text = buf.getvalue()
    # matplotlib's RDF block names web addresses (never fetched, but a page that opens offline should not name them)
    return re.sub(r"<metadata>.*?</metadata>", "", text[text.index("<svg"):], flags=re.S)


def figure(svg_text: str, caption: str) -> str:
    return f'<figure class="plot">{svg_text}<figcaption>{caption}</figcaption></figure>'


def table(header: list[str], rows: list[list], num_cols: set[int] | None = None, cls: str = "",
          what_last: bool = False) -> str:
    """Rows of already-formatted cells (strings are escaped; a cell given as ('html', text) is not). what_last: the
    last column explains the row (set in smaller grey type)."""
    num_cols = num_cols or set()

    def cell(i, v, tag):
        raw = v[1] if isinstance(v, tuple) and v and v[0] == "html" else esc(v)
        c = ' class="num"' if i in num_cols and tag == "td" else ""
        if what_last and tag == "td" and i == len(header) - 1:
            c = ' class="what"'
        return f"<{tag}{c}>{raw}</{tag}>"

    head = "".join(cell(i, h, "th") for i, h in enumerate(header))
    body = "".join("<tr>" + "".join(cell(i, v, "td") for i, v in enumerate(r)) + "</tr>" for r in rows)
    return f'<table class="{cls}"><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>'


def kv(items: list[tuple[str, str]]) -> str:
    return '<dl class="kv">' + "".join(f"<dt>{esc(k)}</dt><dd>{esc(v)}</dd>" for k, v in items) + "</dl>"


def page(title: str, body: str) -> str:
    return (f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
            f'<meta name="viewport" content="width=device-width, initial-scale=1">'
            f'<title>{esc(title)}</title><style>{CSS}</style></head>\n<body><main>\n{body}\n</main></body></html>\n')


def write_page(path, text: str, force: bool = False) -> None:
    """Through the project's output rules (bowsynth.io.outfile): a temp file renamed into place, so a failure leaves
    no half page; a symlink is written through, a FIFO written to, a read-only file refused without force."""
    from ..io.outfile import atomic_write

    atomic_write(path, lambda tmp: Path(tmp).write_text(text, encoding="utf-8"), force=force)


def slug(text: str) -> str:
    return re.sub(r"[^a-z0-9]+", "-", str(text).lower()).strip("-") or "x"


def setup_matplotlib():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.rcParams.update({"font.size": 9, "axes.titlesize": 10, "axes.grid": True, "grid.alpha": 0.3,
                         "svg.fonttype": "none"})  # text as text: smaller, and searchable in the page
    return plt
