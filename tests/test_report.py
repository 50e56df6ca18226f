"""Listening reports: pages made from short real renders, opened in headless Debian chromium with the
network blocked: every player loads with the render's duration, the plots are drawn, no console error, and the
metrics table holds the numbers `compare` prints. Plus the listener measures on signals of known content, and the
report path's output rules.

The browser is Debian's `chromium` driven by playwright (no browser download); `make setup` installs both."""

from __future__ import annotations

import json
import math
import os
import stat
import threading
from pathlib import Path

import numpy as np
import pytest
from conftest import run_main, shipped_models, soft_bow_model

ROOT = Path(__file__).resolve().parents[1]
CHROMIUM = "/usr/bin/chromium"
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
         "--disable-component-update", "--no-first-run"]
SR = 44100


# ---------------------------------------------------------------------------------------------------------- browser

@pytest.fixture(scope="module")
def browser():
    pw = pytest.importorskip("playwright.sync_api", reason="playwright is not installed: `make setup` (the test "
                                                            "extra) installs it")
    if not os.access(CHROMIUM, os.X_OK):
        pytest.skip(f"{CHROMIUM} is missing: `make setup` installs Debian's chromium (apt-get install chromium)")
    with pw.sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=FLAGS, headless=True)
        yield b
        b.close()


def open_report(browser, path: Path) -> dict:
    """Open a page from disk with every non-local request refused; wait for each player to load its audio. Returns
    what the tests check: players, plots, tables, console errors and any request that tried to leave the machine."""
    ctx = browser.new_context(service_workers="block", viewport={"width": 1280, "height": 900})
    requests, errors = [], []

    def route(r):
        u = r.request.url
        if u.startswith(("file:", "data:")):
            r.continue_()
        else:
            r.abort()

    ctx.route("**/*", route)
    page = ctx.new_page()
    page.on("request", lambda r: requests.append(r.url))
    page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.goto(path.resolve().as_uri(), wait_until="load")
    # readyState 1 (HAVE_METADATA) and up: the browser decoded the embedded WAV's header and knows its duration
    page.wait_for_function("Array.from(document.querySelectorAll('audio'))"
                           ".every(a => a.readyState >= 1 && isFinite(a.duration))", timeout=30_000)
    info = page.evaluate("""() => ({
        audio: Array.from(document.querySelectorAll('audio')).map(a => ({
            ready: a.readyState, duration: a.duration, expect: parseFloat(a.dataset.seconds),
            error: a.error ? a.error.code : null, title: a.parentElement.querySelector('b').textContent,
            what: a.parentElement.querySelector('span').textContent})),
        plots: Array.from(document.querySelectorAll('figure.plot')).map(f => {
            const s = f.querySelector('svg'); const r = s ? s.getBoundingClientRect() : {width: 0, height: 0};
            return {w: r.width, h: r.height, marks: s ? s.querySelectorAll('path, use, image, rect').length : 0,
                    caption: f.querySelector('figcaption').textContent}; }),
        tables: Array.from(document.querySelectorAll('table')).map(t => ({cls: t.className,
            rows: Array.from(t.querySelectorAll('tr')).map(tr => Array.from(tr.children).map(c => c.textContent))})),
        sections: Array.from(document.querySelectorAll('section[id]')).map(s => s.id),
        text: document.body.innerText })""")
    ctx.close()
    info["requests"] = [u for u in requests if not u.startswith(("file:", "data:"))]
    info["errors"] = errors
    return info


def check_page(info: dict, durations: list[float], plots: int) -> None:
    """What every page must show: players loaded at the render's length, the plots drawn, no error, no network."""
    assert info["requests"] == [], info["requests"]
    assert info["errors"] == [], info["errors"]
    assert len(info["audio"]) == len(durations), [a["title"] for a in info["audio"]]
    for a, d in zip(info["audio"], durations):
        assert a["error"] is None and a["ready"] >= 1, a
        assert a["duration"] == pytest.approx(d, abs=2e-3), (a["title"], a["duration"], d)
        assert a["expect"] == pytest.approx(d, abs=1e-5)
    assert len(info["plots"]) == plots
    for p in info["plots"]:
        assert p["w"] > 300 and p["h"] > 100 and p["marks"] > 20, p


def metrics_cells(info: dict, cls: str = "metrics") -> list[dict]:
    """Each metrics table as {metric name: [cells of the columns]}, with its header row."""
    out = []
    for t in info["tables"]:
        if t["cls"] == cls:
            head, *rows = t["rows"]
            out.append({"head": head, **{r[0]: r[1:-1] for r in rows}})
    return out


def assert_table_holds(table: dict, j: dict) -> None:
    """The page's metrics table: the numbers `compare --json` gives, formatted as `compare` prints them."""
    from bowsynth.analysis.compare import ROWS

    cols = list(j["metrics"])
    assert table["head"][1:-1] == cols
    for key, name, fmt in ROWS:
        want = []
        for c in cols:
            v = j["metrics"][c][key]
            want.append("n/a" if v is None else fmt.format(v))
        assert table[name] == want, (name, table[name], want)


# ----------------------------------------------------------------------------------------------------- the pages

def test_compare_report_point_model(browser, tmp_path, capsys, monkeypatch):
    from bowsynth import Scene
    from bowsynth.engines.operator.choose import covering_model

    # the shipped point model the renderer would pick for F_B 100, asked for by its name
    model = covering_model(Scene(fb=100, duration=0.5), [m for m in shipped_models() if not m.domain.is_range])
    assert model is not None, "no shipped point model plays F_B 100"
    wav, page = tmp_path / "fb100.wav", tmp_path / "fb100.html"
    code, _, err = run_main(["render", "--model", model.path.stem, "--fb", "100", "-d", "0.5", str(wav), "-q"],
                            capsys, monkeypatch)
    assert code == 0, err
    page.write_text("old")
    page.chmod(0o444)  # a read-only report is replaced with --force, keeping its mode (the output rules)
    code, out, err = run_main(["compare", str(wav), "--report", str(page), "--json", "--force"], capsys, monkeypatch)
    assert code == 0, err
    j = json.loads(out)
    assert stat.S_IMODE(page.stat().st_mode) == 0o444
    info = open_report(browser, page)
    check_page(info, [0.5] * 4, plots=4)
    assert [a["title"] for a in info["audio"]] == ["the file", "the truth", "the audio-rate FDM",
                                                   "difference, scaled up"]
    assert "raised by +" in info["audio"][3]["what"]
    [table] = metrics_cells(info)
    assert_table_holds(table, j)
    assert model.id in info["text"] and "point model" in info["text"]
    # the listener table: a point model's harmonics and pitch are close to the truth's
    [lt] = [t for t in info["tables"] if t["cls"] == "listener"]
    harm = float(lt["rows"][1][1])
    assert harm < 0.1
    assert not list(tmp_path.glob(".*tmp")), "a temp file was left beside the report"
    # self-contained: the only addresses in the page are the SVG namespaces (names, never fetched)
    import re

    urls = set(re.findall(r"https?://[^\"'<> ]+", page.read_text()))
    assert urls <= {"http://www.w3.org/2000/svg", "http://www.w3.org/1999/xlink"}, urls


def test_compare_report_range_model_crescendo(browser, tmp_path, capsys, monkeypatch):
    from bowsynth import Scene

    model = soft_bow_model()  # the range model of the whole soft bow, asked for by its name
    assert model.covers(Scene(fb=[(0.0, 50.0), (1.0, 200.0)], vb=0.15, duration=1.0))
    wav, page = tmp_path / "cresc.wav", tmp_path / "cresc.html"
    code, _, err = run_main(["render", "--model", model.path.stem, "--fb", "50@0,200@1", "--vb", "0.15", "-d", "1",
                             str(wav), "-q"], capsys, monkeypatch)
    assert code == 0, err
    code, out, err = run_main(["compare", str(wav), "--report", str(page), "--json"], capsys, monkeypatch)
    assert code == 0, err
    j = json.loads(out)
    info = open_report(browser, page)
    check_page(info, [1.0] * 4, plots=4)
    [table] = metrics_cells(info)
    assert_table_holds(table, j)
    assert "range model" in info["text"] and "50 at 0 s, 200 at 1 s" in info["text"]
    # the range model's weak upper harmonics show in the bars (docs/measures.md): several dB, not hundredths
    [lt] = [t for t in info["tables"] if t["cls"] == "listener"]
    assert float(lt["rows"][1][1]) > 0.5


def test_compare_report_mix_has_a_section_per_worst_note(browser, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    score = tmp_path / "chord.toml"  # examples/chord.toml with short notes
    score.write_text((ROOT / "examples" / "chord.toml").read_text().replace("duration = 2.0", "duration = 0.5"))
    code, _, err = run_main(["score", "--score", str(score), "--mix", "chord.wav", "--stems", "chord.stems", "-q"],
                            capsys, monkeypatch)
    assert code == 0, err
    # the report through a symlink: the link stays, its target gets the page
    (tmp_path / "pages").mkdir()
    target = tmp_path / "pages" / "real.html"
    target.write_text("old")
    link = tmp_path / "chord.html"
    link.symlink_to(target)
    code, out, err = run_main(["compare", "chord.wav", "--report", str(link), "--report-notes", "2", "--json"],
                              capsys, monkeypatch)
    assert code == 0, err
    rows = json.loads(out)
    assert link.is_symlink() and target.read_text().startswith("<!DOCTYPE html>")
    info = open_report(browser, link)
    stems = [read_len(tmp_path / "chord.stems" / r["note"]["file"]) for r in rows]
    nmse = [r["metrics"][list(r["metrics"])[0]]["nmse"] for r in rows]
    worst = sorted(range(len(rows)), key=lambda i: -nmse[i])[:2]
    assert info["sections"] == [f"note-{i}" for i in worst]
    mix_len = read_len(tmp_path / "chord.wav")
    check_page(info, [mix_len] + [stems[i] for i in worst for _ in range(4)], plots=8)
    notes = [t for t in info["tables"] if t["cls"] == "notes"][0]["rows"][1:]
    assert len(notes) == 3
    for r, row in zip(rows, notes):  # the notes table: compare's numbers against the truth
        m = r["metrics"][list(r["metrics"])[0]]
        assert row[3:6] == [f"{m['nmse']:.3g}", f"{m['cents']:+.3f}", f"{m['harmonic_error_db']:.3f}"]
    for table, i in zip(metrics_cells(info), worst):
        assert_table_holds(table, rows[i])


def read_len(path) -> float:
    import soundfile as sf

    return sf.info(str(path)).duration


def test_models_report(browser, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)  # the shipped models only
    page = tmp_path / "models.html"
    # a 3 x 3 grid: the soft bow's box reaches v_B 0, where the lowest row does not speak; six bows still do. Three
    # validated models (--only): one point model, two range models, the other one's box above v_B 0; every model's
    # report renders for a minute
    shipped = [m for m in shipped_models() if m.failure is None]
    low = soft_bow_model()
    point = next(m for m in shipped if not m.domain.is_range)
    other = next(m for m in shipped if m.domain.is_range and m.domain.box[2] > 0)
    assert low.domain.box[2] == 0, low.domain.box
    names = [m.path.stem for m in (low, point, other)]
    code, out, err = run_main(["models", "--report", str(page), "--report-grid", "3", "--only", ",".join(names)],
                              capsys, monkeypatch)
    assert code == 0, err
    assert f"models report: {low.path.name}: bow 9/9" in err  # progress lines
    assert "does not speak within" in err
    from bowsynth.engines.operator.choose import scan_models

    found = [(p, m) for p, m, _ in scan_models() if p.stem in names]
    points = [p for p, m in found if m is not None and not m.domain.is_range]
    ranges = [p for p, m in found if m is not None and m.domain.is_range]
    assert len(points) == 1 and len(ranges) == 2
    rows = out.split("report written")[0].splitlines()[1:]  # the table's rows, before the line after it
    listed = [l.split()[0] for l in rows if l.strip()]
    assert sorted(listed) == sorted(names), out
    info = open_report(browser, page)
    # a point model: its own scene, model and truth; a range model: best, median, worst of the held-out bows, each
    # model and truth; all 1 s renders. One map per range model.
    check_page(info, [1.0] * (2 * len(points) + 6 * len(ranges)), plots=len(ranges))
    titles = [a["title"] for a in info["audio"]]
    assert sum(t.startswith("model, ") for t in titles) == sum(t.startswith("truth, ") for t in titles)
    assert sum(t.startswith("model, worst") for t in titles) == len(ranges)
    summary = [t for t in info["tables"] if t["cls"] == "summary"][0]["rows"][1:]
    assert [r[0] for r in summary] == [p.name for p, _ in found]
    assert all(f"model-{p.stem}" in info["sections"] for p in points + ranges)
    assert "pitch error" in info["plots"][0]["caption"]


def test_a_validation_grid_says_whether_the_model_rests_where_the_truth_rests():
    # validate_range's records say, per grid bow, whether the truth and the model sound
    from bowsynth.report.models_page import _validation_table

    pts = [{"beta": 2.0, "vb": 0.04, "speaks": False, "truth_sounds": False, "op_sounds": False},
           {"beta": 1.7, "vb": 0.065, "speaks": False, "truth_sounds": False, "op_sounds": True},
           {"beta": 1.7, "vb": 0.2, "speaks": True, "truth_sounds": True, "op_sounds": True, "nmse": 0.01},
           {"beta": 0.3, "vb": 0.0, "speaks": False}]  # an older record: the column as before
    html = _validation_table({"grid": 2, "seconds": 1.0, "ref_oversample": 100, "points": pts})
    assert html.count("no; the model rests") == 1 and html.count("no; the model sounds") == 1
    assert html.count(">yes<") == 1 and html.count(">no<") == 1, html


# ------------------------------------------------------------------------------------------- output rules, bad input

def test_report_path_rules_before_any_work(tmp_path, capsys, monkeypatch):
    wav = tmp_path / "x.wav"
    wav.write_bytes(b"not read: the report path is refused first")
    (tmp_path / "dir.html").mkdir()
    ro = tmp_path / "ro.html"
    ro.write_text("keep")
    ro.chmod(0o444)
    for path, words in ((tmp_path / "dir.html", "is a directory"), (ro, "read-only"), (tmp_path / "r.txt", ".html"),
                        (Path("-"), "not - (standard output)"), (tmp_path / "no" / "r.html", "does not exist")):
        code, _, err = run_main(["compare", str(wav), "--report", str(path)], capsys, monkeypatch)
        assert code == 2 and words in err and err.count("\n") == 1, (path, err)
    assert ro.read_text() == "keep"
    code, _, err = run_main(["models", "--report", str(ro)], capsys, monkeypatch)
    assert code == 2 and "read-only" in err
    code, _, err = run_main(["models", "--report", str(tmp_path / "m.html"), "--report-grid", "0"], capsys,
                            monkeypatch)
    assert code == 2 and "--report-grid" in err
    known = [m.path.stem for m in shipped_models()]
    for only, words in ((f"{known[0]},no-such-model", "no model named no-such-model"), (" , ", "no name given")):
        code, _, err = run_main(["models", "--report", str(tmp_path / "m.html"), "--only", only], capsys, monkeypatch)
        assert code == 2 and words in err and err.count("\n") == 1, err
        assert all(name in err for name in known), err  # the models there are, named
    assert not (tmp_path / "m.html").exists()


def test_no_half_page_when_compare_fails(tmp_path, capsys, monkeypatch):
    import soundfile as sf

    wav = tmp_path / "foreign.wav"  # no bowsynth metadata and no scene flags: compare cannot compare it
    sf.write(str(wav), np.zeros(4410, np.float32), SR, subtype="FLOAT")
    page = tmp_path / "r.html"
    code, _, err = run_main(["compare", str(wav), "--report", str(page)], capsys, monkeypatch)
    assert code == 2 and "no bowsynth metadata" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["foreign.wav"]


def test_report_into_a_fifo_of_a_two_file_comparison(tmp_path, capsys, monkeypatch):
    """Two files (no FDM): the page measures one against the other. A FIFO gets the whole page."""
    for name, fb in (("a.wav", "100"), ("b.wav", "101")):
        code, _, err = run_main(["render", "--method", "fdm", "--fb", fb, "-d", "0.3", str(tmp_path / name), "-q"],
                                capsys, monkeypatch)
        assert code == 0, err
    fifo = tmp_path / "pipe.html"
    os.mkfifo(fifo)
    got = []
    reader = threading.Thread(target=lambda: got.append(fifo.read_bytes()), daemon=True)
    reader.start()
    code, _, err = run_main(["compare", str(tmp_path / "a.wav"), str(tmp_path / "b.wav"), "--report", str(fifo)],
                            capsys, monkeypatch)
    reader.join(10)
    assert code == 0, err
    assert stat.S_ISFIFO(fifo.stat().st_mode)
    text = got[0].decode()
    assert text.startswith("<!DOCTYPE html>") and text.rstrip().endswith("</html>")
    assert text.count("<audio") == 3 and "b.wav" in text  # the two files and their difference


# ------------------------------------------------------------------------------------------- the listener measures

def test_harmonic_levels_each_at_its_own_pitch():
    from bowsynth.report.listen import harmonic_levels_db

    t = np.arange(SR) / SR
    amps = 10 ** (-np.arange(10) * 0.5)  # 0, -10, -20, ... dB
    ref = sum(a * np.sin(2 * np.pi * (k + 1) * 100.0 * t + k) for k, a in enumerate(amps))
    # 0.16 % sharp and harmonic 3 lowered 3 dB: at a shared pitch harmonic 10 would smear (docs/measures.md)
    x = sum(a * (10 ** (-3 / 20) if k == 2 else 1) * np.sin(2 * np.pi * (k + 1) * 100.16 * t + 2 * k)
            for k, a in enumerate(amps))
    h = harmonic_levels_db(x, ref, SR)
    np.testing.assert_allclose(h["levels_ref_db"], -10 * np.arange(10), atol=1e-6)
    want = np.zeros(10)
    want[2] = -3
    np.testing.assert_allclose(h["diff_db"], want, atol=0.01)
    assert h["f0_hz"] == pytest.approx(100.16, rel=1e-5)


def test_onset_and_pitch_track():
    from bowsynth.metrics import onset_time
    from bowsynth.report.listen import cents, pitch_track

    t = np.arange(SR) / SR
    env = np.clip(t / 0.2, 0, 1)  # a linear swell to full level at 0.2 s: half level at 0.1 s
    x = env * np.sin(2 * np.pi * 200 * t)
    assert onset_time(x, SR, 200.0) == pytest.approx(0.1 + 0.5 / 200, abs=1e-3)  # the window ends a period late
    assert math.isnan(onset_time(np.zeros(SR), SR, 200.0))
    tt, f = pitch_track(np.sin(2 * np.pi * 200 * 2 ** (10 / 1200) * t), SR, 200.0)
    _, fr = pitch_track(np.sin(2 * np.pi * 200 * t), SR, 200.0)
    np.testing.assert_allclose(cents(f, fr), 10.0, atol=0.05)
    assert tt[0] > 0 and tt[-1] < 1


def test_makefile_installs_the_browser():
    """CI runs these tests in a browser: `make setup` installs Debian's chromium when it is missing."""
    mk = (ROOT / "Makefile").read_text()
    assert "command -v chromium" in mk and "apt-get install -y chromium" in mk
    assert "playwright" in (ROOT / "pyproject.toml").read_text()


HOSTILE = '<script>window.pwned = 1</script>[bold red]x[/]'


def test_hostile_metadata_in_every_field_is_shown_as_text_never_run(tmp_path, capsys, monkeypatch):
    """A model file's record is data from outside (its digest recomputed, as a forger would): strings in every field
    of its validation, training and selection records reach the models page escaped (no tag of theirs) and the
    render's note as numbers or 'n/a' (no markup), never an internal error."""
    import json

    from safetensors import safe_open
    from safetensors.numpy import save_file

    from bowsynth import Scene
    from bowsynth.engines.operator.modelfile import digest, load_model
    from bowsynth.report.models_page import _meta_card, _validation_table

    model = soft_bow_model()  # a range model that plays the render below, its records those of a validated grid
    assert model.covers(Scene(fb=30, vb=0.2, duration=0.2))
    src = model.path
    with safe_open(str(src), framework="numpy") as f:
        meta = json.loads(f.metadata()["bowsynth"])
        tensors = {k: f.get_tensor(k) for k in f.keys()}
    for k in ("seconds", "ref_oversample", "grid", "nmse", "nmse_max", "harm_db_median", "cents_abs_max"):
        meta["validation"][k] = HOSTILE
    meta["validation"]["points"] = [{k: HOSTILE for k in ("beta", "vb", "nmse", "cents", "lsd_db")}]
    meta["training"].update({k: HOSTILE for k in ("seconds", "steps_done", "optimizer", "final_loss")})
    meta["digest"] = digest(meta, tensors)
    path = tmp_path / "models" / "hostile.safetensors"
    path.parent.mkdir()
    save_file(tensors, str(path), metadata={"bowsynth": json.dumps(meta)})
    m = load_model(path)
    html = _validation_table(m.meta.validation) + _meta_card(path, m)
    assert "<script" not in html and "&lt;script&gt;" in html
    monkeypatch.chdir(tmp_path)
    code, out, err = run_main(["render", "--model", str(path), "--fb", "30", "--vb", "0.2", "-d", "0.2",
                               str(tmp_path / "h.wav")], capsys, monkeypatch)
    assert code == 0, err
    note = [ln for ln in out.splitlines() if "its validation" in ln]
    assert note and "<script" not in note[0] and "[bold" not in note[0] and "n/a" in note[0], out
