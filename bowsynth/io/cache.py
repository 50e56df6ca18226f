"""A small on-disk cache of measured numbers (the sounding ratios of `pitch`) and computed arrays (a model's trunk on
its grid), kept between processes.

Why: `render --pitch A4` solves for the f0 that sounds at A4 by running the FDM from rest a few times; that costs a
fraction of a second per process (the runs; numba's import and load added ~0.8 s before the compiled core), every time the same note is asked for. The
answer depends only on (F_B / w, v_B, a) and the measuring code, so it is kept in one JSON file per table under

    $BOWSYNTH_CACHE, else $XDG_CACHE_HOME/bowsynth, else ~/.cache/bowsynth     (BOWSYNTH_CACHE=off: no cache)

A cache is never a reason to fail: a file that cannot be read, parsed or written, or that was written by another
version of the measurement, is ignored (and replaced when it can be). Writes go to a temporary file in the same
directory, then replace the old one (two processes writing at once: the last one's table wins, nothing is torn).
"""

from __future__ import annotations

import contextlib
import json
import os
import secrets
from pathlib import Path

import numpy as np

CACHE_ENV = "BOWSYNTH_CACHE"
MAX_ENTRIES = 20_000  # a table this size is ~2 MB of JSON; older entries go first


def cache_dir() -> Path | None:
    v = os.environ.get(CACHE_ENV)
    if v is not None:
        return None if v.strip().lower() in ("", "off", "0", "none") else Path(v)
    xdg = os.environ.get("XDG_CACHE_HOME")
    if xdg:
        return Path(xdg) / "bowsynth"
    try:
        home = Path.home()  # a user with no HOME and no passwd entry has none: then no cache, as documented
    except (RuntimeError, KeyError, OSError):
        return None
    return home / ".cache" / "bowsynth"


MAX_TABLE_BYTES = 4 * MAX_ENTRIES * 100  # a table is ~100 bytes an entry; more is not ours


@contextlib.contextmanager
def _regular(path: Path, max_bytes: int):
    """The file open for binary reading, or None for anything that is not a regular file of at most max_bytes: a
    FIFO would block the read forever, a device or a huge file is not ours. OSError where it cannot be opened."""
    import stat

    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode) or st.st_size > max_bytes:
            yield None
        else:
            with os.fdopen(fd, "rb", closefd=False) as fh:
                yield fh
    finally:
        os.close(fd)


def _read_table(path: Path) -> str | None:
    """The table's text, or None for anything that is not a regular file of a sane size."""
    with _regular(path, MAX_TABLE_BYTES) as fh:
        return None if fh is None else fh.read(MAX_TABLE_BYTES + 1).decode("utf-8")


class DiskTable:
    """A JSON table of key -> value (both JSON-able), valid for one `version` of whatever computed the values."""

    def __init__(self, name: str, version: str):
        self.name, self.version = name, version
        self._data: dict | None = None

    def _path(self) -> Path | None:
        d = cache_dir()
        return None if d is None else d / f"{self.name}.json"

    def _load(self) -> dict:
        if self._data is None:
            self._data = {}
            path = self._path()
            try:
                text = _read_table(path) if path is not None else None
                doc = json.loads(text) if text is not None else None
                if isinstance(doc, dict) and doc.get("version") == self.version and isinstance(doc.get("entries"),
                                                                                                 dict):
                    self._data = doc["entries"]
            except (OSError, ValueError, UnicodeDecodeError, RecursionError):
                pass
        return self._data

    def get(self, key: str):
        return self._load().get(key)

    def put(self, key: str, value) -> None:
        data = self._load()
        data[key] = value
        while len(data) > MAX_ENTRIES:
            data.pop(next(iter(data)))
        path = self._path()
        if path is not None:
            text = json.dumps({"version": self.version, "entries": data}, separators=(",", ":"))
            _replace(path, lambda fh: fh.write(text.encode()))


def _replace(path: Path, write) -> None:
    """write(binary file) into a temporary file beside `path`, then move it in place: two processes writing at once
    leave one whole file; a failure leaves the old one (or none) and is ignored."""
    tmp = path.parent / f".{path.name}.{secrets.token_hex(4)}.tmp"
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(tmp, "wb") as fh:
            write(fh)
        os.replace(tmp, path)
    except OSError:
        pass
    finally:
        try:
            tmp.unlink()
        except OSError:
            pass


MAX_ARRAY_BYTES = 64 << 20  # an array cached here is a few MB (a model's trunk grid: 8 MB at 64 features)


def read_array(name: str, shape: tuple, dtype=np.float64):
    """The array cached under `name` (a .npy file in the cache directory) if it is a regular file holding exactly
    that shape and dtype, all finite; else None (never an error: a cache is only ever a shortcut)."""
    d = cache_dir()
    if d is None:
        return None
    try:
        with _regular(d / f"{name}.npy", MAX_ARRAY_BYTES) as fh:
            if fh is None:
                return None
            a = np.load(fh, allow_pickle=False)
    except (OSError, ValueError, EOFError):
        return None
    if a.shape != tuple(shape) or a.dtype != np.dtype(dtype) or not np.all(np.isfinite(a)):
        return None
    return a


def write_array(name: str, a) -> None:
    """Cache `a` under `name`, written to a temporary file and moved in place (nothing torn; a failure is ignored)."""
    d = cache_dir()
    if d is None:
        return
    _replace(d / f"{name}.npy", lambda fh: np.save(fh, np.ascontiguousarray(a), allow_pickle=False))
