"""A small on-disk cache of measured numbers (sounding ratios, auto windows' scores, models' digests and physics
verdicts) and computed arrays (a model's trunk on its grid), kept between processes.

Why: `render --pitch A4` solves for the f0 that sounds at A4 by running the FDM from rest a few times, and auto windows
score a model at a bow by notes from rest against a x10 FDM: a fraction of a second to seconds per process, every time
the same note is asked for. Each answer depends only on its key and the measuring code (the table's version), so it is
kept, one small JSON file an entry (DiskTable), under

    $BOWSYNTH_CACHE, else $XDG_CACHE_HOME/bowsynth, else ~/.cache/bowsynth     (BOWSYNTH_CACHE=off: no cache)

A cache is never a reason to fail: a file that cannot be read, parsed or written, or that was written by another
version of the measurement, is ignored (and replaced when it can be). Writes go to a temporary file in the same
directory, then replace the old one: nothing is torn, and two processes writing at once both keep what they wrote.
The cache is data from outside: its readers check every value's type and range before use, it follows no symlink
below its own directory (a table whose directory is a link is no table), and it removes only files named as it names
them (a table's entries, its version directories, the trunk arrays): whatever a user put there stays.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import secrets
import shutil
import stat
import time
from pathlib import Path

import numpy as np

CACHE_ENV = "BOWSYNTH_CACHE"


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


@contextlib.contextmanager
def _regular(path: Path, max_bytes: int):
    """The file open for binary reading, or None for anything that is not a regular file of at most max_bytes: a
    FIFO would block the read forever, a device or a huge file is not ours. OSError where it cannot be opened."""
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


MAX_ENTRIES = 10_000  # a table's entries on disk (~4 KB each on most file systems); past it the oldest go first
MAX_ENTRY_BYTES = 1 << 20  # an entry is 0.1-3 KB; a bigger file is not ours
KEEP_VERSIONS = 2  # a table's versions kept side by side (two installs of bowsynth used in turn keep theirs)


def _digest(text: str) -> str:
    import hashlib

    return hashlib.blake2b(text.encode(), digest_size=12).hexdigest()


def _ours(name: str, suffix: str = "") -> bool:
    """Whether a file or directory name is one the cache writes: a 24-hex-digit digest (with `suffix`)."""
    stem = name[:-len(suffix)] if suffix and name.endswith(suffix) else (name if not suffix else "")
    return len(stem) == 24 and all(c in "0123456789abcdef" for c in stem)


def _real_dirs(root: str, path: str) -> bool:
    """Whether every component of `path` below `root` (the cache's own directory, which may itself be a link the user
    chose) is a directory and not a symbolic link, or does not exist yet."""
    rel = os.path.relpath(path, root)
    if rel.startswith(os.pardir):
        return False
    cur = root
    for part in [] if rel == os.curdir else rel.split(os.sep):
        cur = os.path.join(cur, part)
        try:
            st = os.lstat(cur)
        except FileNotFoundError:
            return True
        except OSError:
            return False
        if not stat.S_ISDIR(st.st_mode):
            return False
    return True


class DiskTable:
    """Key -> value (both JSON-able), valid for one `version` of whatever computed the values: one small file an
    entry, <cache>/<name>/<version's digest>/<key's digest>.json, holding the version and the key beside the value.

    Why a file an entry and not one file a table: with one file a process reads and parses the whole table to find
    one entry (a table of 2.4 MB cost ~50 ms of every render's process), rewrites all of it for each entry it adds,
    and two processes at work at once each write back the table they read, so one loses the other's new entries. A file an entry costs one small read
    however many entries there are, and is written alone, atomically: nothing another process wrote is lost."""

    def __init__(self, name: str, version: str):
        self.name, self.version = name, version
        self._seen: dict = {}
        self._where: tuple | None = None
        self._tidied: str | None = None  # the directory whose other versions this process has removed

    def _dir(self) -> str | None:
        # a render looks up ~50 entries (its models' digests): the directory is worked out once per environment
        env = tuple(os.environ.get(k) for k in (CACHE_ENV, "XDG_CACHE_HOME", "HOME"))
        if self._where is None or self._where[0] != env:
            d = cache_dir()
            self._where = (env, None if d is None else os.path.join(d, self.name, _digest(self.version)))
        return self._where[1]

    def _file(self, key: str) -> str | None:
        d = self._dir()
        return None if d is None else os.path.join(d, f"{_digest(key)}.json")

    def entry_path(self, key: str) -> Path | None:
        """Where the entry of `key` is kept (None: no cache)."""
        f = self._file(key)
        return None if f is None else Path(f)

    def get(self, key: str):
        if key in self._seen:
            return self._seen[key]
        path = self._file(key)
        if path is None or not _real_dirs(str(cache_dir()), os.path.dirname(path)):
            return None
        try:
            with _regular(path, MAX_ENTRY_BYTES) as fh:
                doc = None if fh is None else json.loads(fh.read(MAX_ENTRY_BYTES + 1).decode("utf-8"))
        except (OSError, ValueError, UnicodeDecodeError, RecursionError):
            return None
        # the key and version stored beside the value: a digest's collision or a file moved between tables misses
        if not (isinstance(doc, dict) and doc.get("version") == self.version and doc.get("key") == key):
            return None
        self._seen[key] = doc.get("value")
        return self._seen[key]

    def put(self, key: str, value) -> None:
        self._seen[key] = value
        path = self.entry_path(key)
        if path is None:
            return
        text = json.dumps({"version": self.version, "key": key, "value": value}, separators=(",", ":"))
        if not _real_dirs(str(cache_dir()), str(path.parent)):  # a link in the table's place: not the cache's
            return
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
        except OSError:  # a file where the directory would be, or no right to write: no cache, never an error
            return
        _replace(path, lambda fh: fh.write(text.encode()))
        _prune_entries(path.parent)
        if self._tidied != str(path.parent):  # other versions and an old table go once a process, not at every put
            _prune_versions(path.parent)
            self._tidied = str(path.parent)


_TMP = re.compile(r"\..+\.[0-9a-f]{8}\.tmp")
STALE_TMP_SECONDS = 3600  # a temporary file this old was left by a process killed while it wrote (an array: 8 MB)


def _scan(d, suffix: str) -> list:
    """The regular files in `d` named *suffix; a writer's temporary file older than STALE_TMP_SECONDS is removed on
    the way (nothing else would ever remove it)."""
    found, stale = [], time.time() - STALE_TMP_SECONDS
    with os.scandir(d) as it:
        for e in it:
            if not e.is_file(follow_symlinks=False):
                continue
            if e.name.endswith(suffix):
                found.append(e)
            elif _TMP.fullmatch(e.name):  # _replace's temporary name
                with contextlib.suppress(OSError):
                    if e.stat(follow_symlinks=False).st_mtime < stale:
                        os.unlink(e.path)
    return found


def _prune_entries(d: Path) -> None:
    """Keep a table's newest MAX_ENTRIES entries. Whatever cannot be listed or removed stays."""
    with contextlib.suppress(OSError):
        entries = _scan(d, ".json")
        entries = [e for e in entries if _ours(e.name, ".json")]
        if len(entries) > MAX_ENTRIES:
            entries.sort(key=lambda e: e.stat(follow_symlinks=False).st_mtime_ns)
            for e in entries[:len(entries) - MAX_ENTRIES * 9 // 10]:
                with contextlib.suppress(OSError):
                    os.unlink(e.path)


def _prune_versions(d: Path) -> None:
    """Keep a table's KEEP_VERSIONS newest versions; remove the one-file table an older bowsynth wrote beside it
    (<name>.json). Whatever cannot be listed or removed stays."""
    with contextlib.suppress(OSError):
        with os.scandir(d.parent) as it:
            versions = [e for e in it if e.is_dir(follow_symlinks=False) and e.name != d.name and _ours(e.name)]
        versions.sort(key=lambda e: e.stat(follow_symlinks=False).st_mtime_ns, reverse=True)
        for e in versions[KEEP_VERSIONS - 1:]:
            shutil.rmtree(e.path, ignore_errors=True)
    old = d.parent.parent / f"{d.parent.name}.json"
    with contextlib.suppress(OSError):
        if stat.S_ISREG(os.lstat(old).st_mode):
            os.unlink(old)


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
# All arrays together: ~30 models' trunk grids at 64 features. Unbounded, each model retrained or replaced (its id
# changes) would leave its old 8 MB behind for good; the least recently used go first (one is computed again in
# ~0.1-0.2 s).
MAX_ARRAYS_TOTAL = 256 << 20


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
            if a.shape != tuple(shape) or a.dtype != np.dtype(dtype) or not np.all(np.isfinite(a)):
                return None
            with contextlib.suppress(OSError):  # its change time marks it used: the bound removes the unused first
                os.utime(fh.fileno())
    except (OSError, ValueError, EOFError):
        return None
    return a


def write_array(name: str, a) -> None:
    """Cache `a` under `name`, written to a temporary file and moved in place (nothing torn; a failure is ignored)."""
    d = cache_dir()
    if d is None:
        return
    _replace(d / f"{name}.npy", lambda fh: np.save(fh, np.ascontiguousarray(a), allow_pickle=False))
    _prune_arrays(d, f"{name}.npy")


def _prune_arrays(d: Path, keep: str) -> None:
    """Keep the most recently used arrays within MAX_ARRAYS_TOTAL bytes, and always `keep` (the one just written).
    Only regular *.npy files are counted or removed: a link or anything else a user put there stays."""
    with contextlib.suppress(OSError):
        files = [(e.stat(follow_symlinks=False), e) for e in _scan(d, ".npy") if e.name.startswith("trunk-")]
        files.sort(key=lambda f: f[0].st_mtime_ns, reverse=True)
        total = 0
        for st, e in files:
            total += st.st_size
            if total > MAX_ARRAYS_TOTAL and e.name != keep:
                with contextlib.suppress(OSError):
                    os.unlink(e.path)
