"""Output paths: where the bytes of a file land, and how they get there without half a file or a stray temp file.

- a regular file (new or existing) is written to a temp file in its own directory, then renamed over it: a reader
  never sees half a file, and a failure or a signal leaves the old file as it was. An existing file keeps its
  permission bits; a read-only one (no write bit in its mode, checked from the bits so that root is refused too)
  is replaced only with force=True.
- a symlink is written through: the link stays, its target gets the file (atomically in the target's directory).
- a FIFO or a character device (/dev/null, a terminal) is written to directly: never replaced, never unlinked.
  The file is first made complete in a private temp file, then copied in, so a FIFO reader gets a whole file.
- "-" is standard output (binary); a terminal is refused.
"""

from __future__ import annotations

import os
import secrets
import shutil
import stat
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

from ..errors import BowsynthError, UsageError

STDOUT = "-"


@dataclass(frozen=True)
class Target:
    """Where an output path's bytes go. kind: 'stdout', 'special' (FIFO or character device) or 'file'."""

    path: Path  # as given
    real: Path  # symlinks resolved (== path for stdout)
    kind: str
    mode: int | None = None  # permission bits of an existing regular file, kept when it is replaced
    in_place: bool = False  # the directory is not writable but the file is: no temp file beside it

    @property
    def is_stdout(self) -> bool:
        return self.kind == "stdout"


def is_stdout(path) -> bool:
    return str(path) == STDOUT


def _read_only(st: os.stat_result, real: Path) -> bool:
    # the mode bits first: root passes os.access on any file, yet a 0444 file says "do not overwrite me"
    return not (st.st_mode & 0o222) or not os.access(real, os.W_OK)


def resolve(path, force: bool = False) -> Target:
    """Check that `path` can be written and say how; raises UsageError (before any work) when it cannot."""
    if is_stdout(path):
        if sys.stdout is None or not hasattr(sys.stdout, "buffer"):
            raise UsageError("no standard output to write to")
        if sys.stdout.isatty():
            raise UsageError("refusing to write binary audio to a terminal; redirect standard output or give a file")
        _temp_dir()
        return Target(Path(STDOUT), Path(STDOUT), "stdout")
    p = Path(path)
    if str(p) == "":
        raise UsageError("empty output path")
    try:
        str(p).encode("utf-8")
    except UnicodeEncodeError:  # bytes no text encoding holds: every message naming the file would fail
        raise UsageError(f"output name {ascii(str(p))} is not valid UTF-8; give a name in UTF-8") from None
    try:
        real = Path(os.path.realpath(p)) if p.is_symlink() else p
        st = os.stat(real)
    except FileNotFoundError:
        st = None
    except NotADirectoryError:
        raise UsageError(f"output directory {real.parent} does not exist (a file has that name)") from None
    except OSError as e:  # a symlink loop, a path through a file, ...
        raise UsageError(f"output path {p} cannot be used ({e.strerror})") from None
    via = f" (the target of the symlink {p})" if real != p else ""
    if st is not None:
        if stat.S_ISDIR(st.st_mode):
            raise UsageError(f"output path {real}{via} is a directory; give a file name")
        if stat.S_ISFIFO(st.st_mode) or stat.S_ISCHR(st.st_mode):
            if not os.access(real, os.W_OK):
                raise UsageError(f"{real}{via} is not writable")
            _temp_dir()
            return Target(p, real, "special")
        if not stat.S_ISREG(st.st_mode):
            raise UsageError(f"output path {real}{via} is not a regular file, FIFO or character device")
        if _read_only(st, real) and not force:
            raise UsageError(f"{real}{via} is read-only (mode {stat.S_IMODE(st.st_mode):o}); pass --force to replace it")
    parent = real.parent if str(real.parent) else Path(".")
    if not parent.is_dir():
        raise UsageError(f"output directory {parent} does not exist")
    if not os.access(parent, os.W_OK):
        if st is not None and os.access(real, os.W_OK):
            return Target(p, real, "file", stat.S_IMODE(st.st_mode), in_place=True)
        raise UsageError(f"output directory {parent} is not writable")
    return Target(p, real, "file", None if st is None else stat.S_IMODE(st.st_mode))


def _temp_dir() -> str:
    """The temporary directory a FIFO, device or stdout output is made in, checked before any work (with /tmp,
    /var/tmp and the working directory all read-only, Python finds none: once a FileNotFoundError after rendering)."""
    try:
        return tempfile.gettempdir()
    except FileNotFoundError:
        raise BowsynthError("no writable temporary directory (tried $TMPDIR, /tmp, /var/tmp and the working "
                            "directory): set TMPDIR to a writable directory") from None


def check_not_input(output, inputs, flag: str) -> None:
    """Refuse an output that is one of the command's inputs (the same file by any name: the path, a hard link, a
    symlink to it), or a directory that holds one: writing it would replace what the command reads. UsageError."""
    if output is None or is_stdout(output):
        return
    out = Path(output)
    for inp in inputs:
        if inp is None or is_stdout(inp):
            continue
        try:
            same = out.exists() and Path(inp).exists() and os.path.samefile(out, inp)
        except OSError:
            same = False
        if same:
            raise UsageError(f"{flag} {output} is the input {inp} (the same file): writing it would replace what "
                             f"this command reads; choose another name")


def check_output_path(path, force: bool = False) -> Path:
    """Fail early, before any work, when an output path can't be written. Returns the path as given."""
    return resolve(path, force).path


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _new_temp(directory: Path, name: str, suffix: str) -> str:
    # the name is chosen before the file exists, so a signal between creating it and noting it cannot leak it
    return str(directory / f".{name}.{secrets.token_hex(4)}{suffix}")


def atomic_write(path, write, force: bool = True, exclusive: bool = False) -> None:
    """Call write(tmp_path) on a temp file, then put the result at `path` as the module docstring describes.

    The temp file is removed on every exit path (errors, KeyboardInterrupt, and SIGTERM, which the CLI raises as a
    KeyboardInterrupt subclass). OS errors become one-line BowsynthErrors naming the path.
    """
    t = resolve(path, force=force)
    if t.kind == "file" and not t.in_place:
        tmp = _new_temp(t.real.parent if str(t.real.parent) else Path("."), t.real.name, ".tmp")
    else:  # the complete file is made privately, then copied to the device, FIFO, stdout or unrenamable file
        tmp = _new_temp(Path(tempfile.gettempdir()), "bowsynth", t.real.suffix)
    try:
        try:
            os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))
            write(tmp)
            if t.kind == "file" and not t.in_place:
                os.chmod(tmp, t.mode if t.mode is not None else 0o666 & ~_umask())
                if exclusive:  # a link refuses an existing name: nothing that appeared since the check is replaced
                    os.link(tmp, t.real)
                else:
                    os.replace(tmp, t.real)
            else:
                _copy_into(tmp, t)
        except FileExistsError:
            raise
        except (OSError, RuntimeError) as e:  # libsndfile reports a full disk as RuntimeError("System error.")
            where = "standard output" if t.is_stdout else str(t.real)
            why = getattr(e, "strerror", None) or str(e).rstrip(".")
            raise BowsynthError(f"could not write {where}: {why}{_full(tmp)}; the old file, if any, is unchanged"
                                ) from None
    finally:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass


def _full(path) -> str:
    """' (its disk is full)' when the filesystem holding `path` has under a megabyte free: libsndfile says only
    'System error'."""
    try:
        st = os.statvfs(os.path.dirname(os.path.abspath(path)) or ".")
    except OSError:
        return ""
    return " (its disk is full)" if st.f_bavail * st.f_frsize < 1024**2 else ""


def _copy_into(tmp: str, t: Target) -> None:
    with open(tmp, "rb") as src:
        if t.is_stdout:
            sys.stdout.flush()
            shutil.copyfileobj(src, sys.stdout.buffer)
            sys.stdout.buffer.flush()
            return
        # no O_CREAT: if the FIFO or device vanished since the check, do not create a regular file in its place
        flags = os.O_WRONLY | (os.O_TRUNC if t.kind == "file" else 0)
        with os.fdopen(os.open(t.real, flags), "wb") as dst:
            shutil.copyfileobj(src, dst)
