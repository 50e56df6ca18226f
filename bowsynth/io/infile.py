"""Input files: what a reader says when the path it is given is not a regular file it can read.

Every reader (model files, audio, scores, MIDI) asks this once before it opens a path: a FIFO blocks its reader until
someone writes to it, and a device such as /dev/zero never ends, so neither is ever opened; and "not found" is said
only of a path that is not there (a directory, a pipe from a shell's `<(...)` or /dev/null were all "not found").
"""

from __future__ import annotations

import errno
import os
import stat
from pathlib import Path

from ..errors import UsageError


def regular_file(path, what: str, noun: str, error: type[Exception] = UsageError) -> os.stat_result:
    """The stat of `path` where it is a regular file (a symlink to one included); else `error` with one line:
    '{what} PATH not found' (a symlink to nothing said), is a symlink loop, cannot be read (why), or is a
    directory / a FIFO / a device, 'not {noun}'."""
    p = Path(path)
    try:
        st = os.stat(p)
    except FileNotFoundError:
        raise error(f"{what} {p} not found" + (" (a symlink to nothing)" if p.is_symlink() else "")) from None
    except OSError as e:
        why = "is a symlink loop" if e.errno == errno.ELOOP else f"cannot be read ({e.strerror})"
        raise error(f"{what} {p} {why}") from None
    if stat.S_ISREG(st.st_mode):
        return st
    if stat.S_ISDIR(st.st_mode):
        kind = "a directory"
    elif stat.S_ISFIFO(st.st_mode):
        kind = "a FIFO"
    elif stat.S_ISCHR(st.st_mode) or stat.S_ISBLK(st.st_mode):
        kind = "a device"
    else:
        kind = "not a regular file"
    link = f" (the target of a symlink: {os.path.realpath(p)})" if p.is_symlink() and kind != "a directory" else ""
    raise error(f"{what} {p} is {kind}{link}, not {noun}")
