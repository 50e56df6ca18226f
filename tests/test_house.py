"""The product speaks of itself in the present: no sitting, round or issue numbers and no paths outside the repository."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# what ships and what measures it; CHANGELOG.md names versions and is not checked
CHECKED = ("bowsynth", "tests", "benchmarks", "docs", "examples", "Makefile", "README.md", "pyproject.toml")
SKIP_DIRS = {".venv", "__pycache__", "build", ".pytest_cache", ".hypothesis"}
BINARY = {".safetensors", ".npz", ".npy", ".png", ".jpg", ".wav", ".flac", ".ogg", ".mid", ".so", ".gz", ".pyc"}
# built from pieces so that this file does not match itself: a sitting ("s-e-s-s-i-o-n 12", "...-19"), a round, an
# issue by number, a scratch folder of one sitting, or a guide kept outside the repository (git log is the history).
# The word and its number may be split over two lines of a comment or docstring.
_S = "sess" + "ion"
_GAP = r"[ \t]*(?:\n[ \t#*>]*)?"
HISTORY = re.compile("|".join([rf"\b{_S}s?{_GAP}\d+", rf"\b{_S}-\d+", r"\bro" + rf"und{_GAP}\d\b",
                               r"\bis" + rf"sue{_GAP}\d+", "scr" + "atch/", "GUI" + r"DE(?:\.md| section)",
                               # in a name: _ro-und2_files, a s-e-s-s-i-o-n_12 table
                               rf"(?<![a-z])(?:{_S}|ro" + "und|is" + r"sue)_?\d+(?!\d)"]),
                     re.IGNORECASE)


def history_lines(text: str) -> list[tuple[int, str]]:
    """The lines of text (numbered from 1) where something tells when or in which sitting it was done."""
    lines = text.splitlines()
    at = sorted({text.count("\n", 0, m.start()) + 1 for m in HISTORY.finditer(text)})
    return [(i, lines[i - 1].strip()) for i in at]


def checked_files() -> list[Path]:
    """The checked paths' files: git's (tracked, and new ones not ignored), else a walk of the checked paths."""
    try:
        out = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard", "-z", "--", *CHECKED],
                             cwd=ROOT, capture_output=True, text=True, timeout=60, check=True).stdout
        names = sorted({n for n in out.split("\0") if n})
    except (OSError, subprocess.SubprocessError):
        names = []
        for top in CHECKED:
            p = ROOT / top
            if p.is_file():
                names.append(top)
            elif p.is_dir():
                names += [str(f.relative_to(ROOT)) for f in p.rglob("*")
                          if f.is_file() and not SKIP_DIRS & set(f.relative_to(ROOT).parts)]
    return [ROOT / n for n in names if Path(n).suffix.lower() not in BINARY]


def read_text(path: Path) -> str | None:
    """The file's text, or None for a missing, binary or non-UTF-8 file."""
    try:
        data = path.read_bytes()
    except OSError:
        return None
    if b"\0" in data[:8192]:
        return None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return None


def test_no_history_in_code_tests_benchmarks_docs_or_recipes():
    files = checked_files()
    assert any(f.name == "Makefile" for f in files) and any(f.suffix == ".toml" for f in files)
    found = []
    for f in files:
        text = read_text(f)
        if text is not None:
            found += [f"{f.relative_to(ROOT)}:{i}: {line}" for i, line in history_lines(text)]
    assert not found, "say it in the present (git log is the history):\n" + "\n".join(found)


def test_the_checker_finds_a_planted_line():
    planted = "\n".join(["x = 1  # a plain comment", "# measured in " + _S + " 37, then fixed",
                         '"""as shipped in ' + _S + "s 19-34, from " + "scr" + 'atch/s35/run.py"""',
                         "# the " + _S + "-19 model", "# ro" + "und 2: files in", "# is" + "sue 11: scores",
                         "# why (" + _S, "# 37): the creep", "see shared/" + "GUI" + "DE.md 9",
                         "def _ro" + "und3_files(d):", "x = " + _S + "_12_table"])
    assert [i for i, _ in history_lines(planted)] == [2, 3, 4, 5, 6, 7, 9, 10, 11]
    # other senses of the words pass: a pytest fixture's scope, Python's round(), a figure rounded to 3 digits
    clean = '@pytest.fixture(scope="' + _S + '")\nn = int(round(t * sr))\n# rounded to 3 digits; the issue is the bow'
    assert history_lines(clean) == []


def test_the_top_level_is_the_cards_layout():
    """The package, the shipped models and presets, the tests and the project files sit at the top of the checkout,
    and the program finds the models and presets there (a wheel carries them inside the package)."""
    from bowsynth import shipped
    from bowsynth.engines.operator.choose import SHIPPED_DIR
    from bowsynth.scene import PRESET_DIR

    for name in ("bowsynth", "models", "presets", "tests"):
        assert (ROOT / name).is_dir(), name
    for name in ("pyproject.toml", "README.md"):
        assert (ROOT / name).is_file(), name
    assert SHIPPED_DIR == shipped("models") == ROOT / "models" and PRESET_DIR == ROOT / "presets"
    assert any(SHIPPED_DIR.glob("*.safetensors")) and (SHIPPED_DIR / "MANIFEST.json").is_file()
    assert not (ROOT / "bowsynth" / "models").exists() and not (ROOT / "bowsynth" / "presets").exists()
