"""Errors that are the user's input or a scene's data, not a bug. A `UserError` is printed by
the CLI as one line (exit status 2); a `SceneDataError` makes one scene a ``data_error`` row.

Subclass `UserError` for any error whose message alone tells the user what to change (a bad
config value, a missing file they named, a tool they have to install). Everything else is a bug
and keeps its traceback.
"""

from __future__ import annotations

import errno


class UserError(Exception):
    """Bad input or a missing prerequisite: one line on stderr, exit status 2, no traceback."""

    exit_code = 2


class ConfigError(UserError, ValueError):
    """A config option, key or value that is not valid."""


class SceneDataError(ValueError):
    """A bad input of one scene (a malformed or missing file): the scene's row is ``data_error``,
    the run goes on. The message is one line naming the file."""


def one_line(text: object) -> str:
    """``text`` with every run of whitespace (newlines included) as one space: an error message
    fit for a table cell or a log line."""
    return " ".join(str(text).split())


#: What a machine, not a scene or a model, does wrong: a full disk or quota, a read-only file
#: system, a folder visphy may not write. Every scene after it would fail the same way, so it
#: stops the run (resumable) instead of becoming a row.
HOST_FAULT_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES,
                               errno.EPERM})
#: Of those, the ones that are the machine's only when a file operation raised them (the
#: error names a file): a refused namespace or signal is the sandbox's business, not this.
FILE_ONLY_ERRNOS = frozenset({errno.EACCES, errno.EPERM})


class HostFault(UserError):
    """The machine refused a write (disk full, read-only, permission): one line on stderr
    naming the path, what was free and needed, and what to do; exit status 74 (EX_IOERR)."""

    exit_code = 74


def host_fault(exc: BaseException | None) -> OSError | None:
    """The `HOST_FAULT_ERRNOS` error in ``exc`` or in the chain of exceptions it was raised
    from or during, else None."""
    seen: set[int] = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        if isinstance(exc, OSError) and exc.errno in HOST_FAULT_ERRNOS and (
                exc.errno not in FILE_ONLY_ERRNOS
                or exc.filename or getattr(exc, "visphy_path", None)):
            return exc
        exc = exc.__cause__ or exc.__context__
    return None


def _size(n: float) -> str:
    for unit in ("B", "KB", "MB", "GB"):
        if abs(n) < 1024 or unit == "GB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024
    return f"{n:.1f} GB"


def _free_bytes(path: str) -> int | None:
    """Bytes free to this user on the file system holding ``path`` (its nearest existing
    parent)."""
    import os

    probe = os.path.abspath(path)
    while probe and not os.path.exists(probe):
        parent = os.path.dirname(probe)
        if parent == probe:
            break
        probe = parent
    try:
        st = os.statvfs(probe)
    except OSError:
        return None
    return st.f_bavail * st.f_frsize


def describe_host_fault(err: OSError, needed_bytes: int | None = None) -> str:
    """One line: what the machine refused, where, what was free and needed."""
    path = err.filename or getattr(err, "visphy_path", None) or "a file"
    needed = needed_bytes if needed_bytes is not None else getattr(err, "visphy_needed", None)
    if err.errno in (errno.ENOSPC, errno.EDQUOT):
        what = "disk full" if err.errno == errno.ENOSPC else "disk quota exceeded"
        free = _free_bytes(str(path)) if path != "a file" else None
        room = f"{_size(free)} free there" if free is not None else "free space unknown"
        need = f", about {_size(needed)} needed" if needed else ""
        return f"{what} writing {path} ({room}{need})"
    if err.errno == errno.EROFS:
        return f"read-only file system: cannot write {path}"
    return (f"permission denied writing {path}: set VISPHY_HOME (or paths.root) to a folder "
            "you can write, or fix its permissions")
