"""Every file visphy reads from a tree it did not write in this process, and every file it
writes into a run directory, goes through this module.

**Foreign files** (`open_untrusted`, `read_bytes`, `read_text`, `read_json`, `open_binary`,
`entry_kind`, `list_dir`): replay sources, run directories being replayed, re-scored, merged,
reported or rated, dataset folders, cache payloads, and the files a sandboxed program wrote
(`sandbox/process.py::read_untrusted`, the frame readers of `png.py` and `video.py` open them
with `open_untrusted` and word its refusals their own way). A path is opened component by
component below the root the user named, each component with ``O_NOFOLLOW`` (directories with
``O_DIRECTORY``), so no symbolic link below that root is ever followed, whatever it points at
(``/proc/self/environ``, another user's file, a directory elsewhere). Files are opened
non-blocking and only regular files are read (no FIFO, device or socket), never more than the
size cap of their kind (`LIMITS`), even when the file grows while it is read. A violation
raises `ForeignFileError`, whose one-line message names the path and why, never a byte of
content; it is a `SceneDataError` (the scene's row is ``data_error``) and a `UserError` (the CLI
prints one line, exit 2). The root itself may be a link: the user named it.

**Writes into a run directory** (`atomic_write`, `append_line`): every directory below the
root is created or opened with ``O_NOFOLLOW``; a file is replaced atomically through a temporary
created with ``O_EXCL | O_NOFOLLOW`` in the same directory and renamed over the name (a rename
replaces a link planted there, it never writes through it). An append opens with
``O_NOFOLLOW`` and only appends to a regular file with one link that this user owns (a file the
run created), never to a link, a hard link to another file, a FIFO or a device.
"""

from __future__ import annotations

import errno
import io
import json
import os
import stat
from pathlib import Path
from typing import Any, BinaryIO, Iterator

from visphy_core.infra.errors import SceneDataError, UserError

MiB = 1 << 20
#: The largest file of each kind visphy reads from a foreign tree (bytes).
LIMITS = {
    "reply": 16 * MiB,      # a model's reply or program
    "text": 16 * MiB,       # logs, analysis text, small sidecars
    "json": 64 * MiB,       # manifests, specs, detections, summaries, score files
    "jsonl": 1024 * MiB,    # results.jsonl, calls.jsonl, ratings
    "video": 4096 * MiB,    # clips
    "image": 256 * MiB,     # key frames, PNG frames
    "array": 1024 * MiB,    # trajectories (.npz)
    "any": 4096 * MiB,      # bytes hashed or copied as they are
}

_DIR_FLAGS = os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW | os.O_CLOEXEC
_FILE_FLAGS = os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC


class ForeignFileError(SceneDataError, UserError):
    """A foreign file that visphy refuses to read (a link, not a regular file, too large, or
    outside its root). The message names the path, never its content; ``why`` says which
    (``"link"``, ``"not_dir"``, ``"not_regular"``, ``"too_large"``, ``"outside"``) for callers
    that word it their own way, and ``size`` is the file's size when it is too large."""

    def __init__(self, message: str, why: str = "other", size: int | None = None):
        super().__init__(message)
        self.why, self.size = why, size


def _violation(path: Path, reason: str, verb: str = "read", *, why: str = "other",
               size: int | None = None) -> ForeignFileError:
    return ForeignFileError(f"refused to {verb} {path}: {reason}", why, size)


def _parts(path: Path, root: Path) -> tuple[str, ...]:
    try:
        rel = Path(path).relative_to(root)
    except ValueError:
        raise _violation(Path(path), f"it is not inside {root}", why="outside") from None
    if any(p in ("..", "") for p in rel.parts):
        raise _violation(Path(path), "the path climbs out of its root ('..')", why="outside")
    return rel.parts


def _why_not_opened(dir_fd: int, name: str, shown: Path, exc: OSError,
                    verb: str = "read") -> Exception:
    """The error for a component that would not open: a violation for a link or a non-directory
    where a directory was needed, the original `OSError` (e.g. missing) otherwise."""
    try:
        st = os.lstat(name, dir_fd=dir_fd)
    except OSError:
        return exc
    if stat.S_ISLNK(st.st_mode):
        return _violation(shown, "it is a symbolic link (links are never followed in a tree "
                          "visphy did not write)", verb, why="link")
    if exc.errno == errno.ENOTDIR:
        return _violation(shown, "a component of the path is not a directory", verb,
                          why="not_dir")
    return exc


def _open_dir(root: Path, parts: tuple[str, ...], create: bool = False,
              verb: str = "read") -> int:
    """An fd of ``root/parts`` opened component by component without following links below
    ``root`` (directories are created, mode 0o755, when ``create``)."""
    fd = os.open(root, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
    shown = Path(root)
    try:
        for part in parts:
            shown = shown / part
            try:
                nfd = os.open(part, _DIR_FLAGS, dir_fd=fd)
            except FileNotFoundError:
                if not create:
                    raise FileNotFoundError(errno.ENOENT, "no such directory", str(shown)) \
                        from None
                try:
                    os.mkdir(part, 0o755, dir_fd=fd)
                except FileExistsError:
                    pass
                nfd = os.open(part, _DIR_FLAGS, dir_fd=fd)
            except OSError as exc:
                raise _why_not_opened(fd, part, shown, exc, verb) from None
            os.close(fd)
            fd = nfd
    except BaseException:
        os.close(fd)
        raise
    return fd


def _root_of(path: Path, root: str | Path | None) -> Path:
    return Path(root) if root is not None else Path(path).parent


def open_untrusted(path: str | Path, max_bytes: int, root: str | Path | None = None, *,
                   what: str | None = None) -> tuple[int, int]:
    """(fd, size) of the untrusted regular file ``path`` below ``root`` (default: its own
    directory): no link below ``root`` followed, opened non-blocking (a FIFO cannot hang the
    caller), a regular file of at most ``max_bytes`` (``what`` names that cap in the message).
    Raises `FileNotFoundError` when it is missing and `ForeignFileError` on a violation, with
    `ForeignFileError.why` saying which (``"link"``, ``"not_regular"``, ``"too_large"`` with
    ``size``, ...); other `OSError` exceptions pass through. The caller closes the fd."""
    path = Path(path)
    base = _root_of(path, root)
    parts = _parts(path, base)
    if not parts:
        raise _violation(path, "it is a directory, not a file", why="not_regular")
    dfd = _open_dir(base, parts[:-1])
    try:
        try:
            fd = os.open(parts[-1], _FILE_FLAGS, dir_fd=dfd)
        except OSError as exc:
            if exc.errno == errno.ENOENT:
                raise FileNotFoundError(errno.ENOENT, "no such file", str(path)) from None
            raise _why_not_opened(dfd, parts[-1], path, exc) from None
    finally:
        os.close(dfd)
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise _violation(path, "it is not a regular file", why="not_regular")
        if st.st_size > max_bytes:
            raise _violation(path, f"it is {st.st_size} bytes, over "
                             f"{what or f'the {max_bytes}-byte limit'}", why="too_large",
                             size=st.st_size)
    except BaseException:
        os.close(fd)
        raise
    return fd, st.st_size


def read_upto(fd: int, count: int) -> bytes:
    """At most ``count`` bytes from ``fd``, fewer at end of file: a file that grows while it is
    read is cut off at ``count``."""
    chunks, left = [], count
    while left > 0:
        chunk = os.read(fd, min(left, MiB))
        if not chunk:
            break
        chunks.append(chunk)
        left -= len(chunk)
    return b"".join(chunks)


def _limit_of(kind: str) -> str:
    return f"the {LIMITS[kind]}-byte limit for a {kind} file"


def read_bytes(path: str | Path, root: str | Path | None = None, *, kind: str = "text") -> bytes:
    """The bytes of the foreign regular file ``path`` (see the module docstring). ``root``: the
    tree the user named (no link below it is followed); default ``path``'s own directory.
    Raises `FileNotFoundError` when it is missing, `ForeignFileError` on a violation."""
    limit = LIMITS[kind]
    fd, _ = open_untrusted(path, limit, root, what=_limit_of(kind))
    try:
        data = read_upto(fd, limit + 1)
    finally:
        os.close(fd)
    if len(data) > limit:  # the file grew while it was read
        raise _violation(Path(path), f"it is over {_limit_of(kind)}", why="too_large")
    return data


def read_text(path: str | Path, root: str | Path | None = None, *, kind: str = "text",
              errors: str = "replace") -> str:
    """`read_bytes` decoded as UTF-8 (undecodable bytes replaced by default)."""
    return read_bytes(path, root, kind=kind).decode("utf-8", errors=errors)


def read_json(path: str | Path, root: str | Path | None = None, *, kind: str = "json") -> Any:
    """`read_bytes` parsed as JSON; a malformed file raises `ValueError` naming the file."""
    data = read_bytes(path, root, kind=kind)
    try:
        return json.loads(data.decode("utf-8"))
    except json.JSONDecodeError as exc:
        raise ValueError(f"malformed JSON in {path}: {exc.msg} (line {exc.lineno})") from None
    except UnicodeDecodeError as exc:
        raise ValueError(f"malformed JSON in {path}: not UTF-8 text (byte {exc.start})") \
            from None


def open_binary(path: str | Path, root: str | Path | None = None, *,
                kind: str = "video") -> BinaryIO:
    """The foreign regular file ``path`` as an open binary file object (for decoders that read
    a stream, e.g. PyAV); the caller closes it."""
    fd, _ = open_untrusted(path, LIMITS[kind], root, what=_limit_of(kind))
    return io.open(fd, "rb", closefd=True)


def entry_kind(path: str | Path, root: str | Path | None = None) -> str | None:
    """``"file"`` (regular), ``"dir"`` or None (missing) for ``path`` below ``root``, looked up
    without following links; a link or special file raises `ForeignFileError`."""
    path = Path(path)
    base = _root_of(path, root)
    parts = _parts(path, base)
    if not parts:
        return "dir" if os.path.isdir(base) else None
    try:
        dfd = _open_dir(base, parts[:-1])
    except FileNotFoundError:
        return None
    try:
        st = os.lstat(parts[-1], dir_fd=dfd)
    except FileNotFoundError:
        return None
    finally:
        os.close(dfd)
    if stat.S_ISREG(st.st_mode):
        return "file"
    if stat.S_ISDIR(st.st_mode):
        return "dir"
    if stat.S_ISLNK(st.st_mode):
        raise _violation(path, "it is a symbolic link (links are never followed in a tree "
                         "visphy did not write)", why="link")
    raise _violation(path, "it is not a regular file", why="not_regular")


def is_file(path: str | Path, root: str | Path | None = None) -> bool:
    """True for a regular file, False when missing or a directory; a link raises."""
    return entry_kind(path, root) == "file"


def list_dir(path: str | Path, root: str | Path | None = None) -> Iterator[tuple[str, str]]:
    """(name, "file" | "dir" | "link" | "other") of each entry of the foreign directory
    ``path``, sorted by name, without following links (the caller decides what a link is)."""
    path = Path(path)
    base = Path(root) if root is not None else path
    fd = _open_dir(base, _parts(path, base))
    try:
        with os.scandir(fd) as it:
            entries = sorted((e.name, e) for e in it)
        out = []
        for name, entry in entries:
            if entry.is_symlink():
                kind = "link"
            elif entry.is_dir(follow_symlinks=False):
                kind = "dir"
            elif entry.is_file(follow_symlinks=False):
                kind = "file"
            else:
                kind = "other"
            out.append((name, kind))
    finally:
        os.close(fd)
    return iter(out)


# ------------------------------------------------------------------ writes into a run directory
def _write_root(path: Path, root: str | Path | None) -> tuple[Path, tuple[str, ...]]:
    base = _root_of(path, root)
    base.mkdir(parents=True, exist_ok=True)
    parts = _parts(path, base)
    if not parts:
        raise _violation(path, "it is a directory, not a file")
    return base, parts


def atomic_write(path: str | Path, data: bytes | str, root: str | Path | None = None, *,
                 fsync: bool = False) -> Path:
    """Write ``data`` (text as UTF-8) to ``path`` atomically: a reader (or a crash) never sees
    half a file. Directories between ``root`` (default: ``path``'s directory, created if
    needed) and the file are created or opened without following links; the temporary is
    created exclusively (``O_EXCL | O_NOFOLLOW``) and renamed over the name, so a link planted
    at either name is replaced, never written through. ``fsync``: flushed to disk before the
    rename (files a resumed run relies on)."""
    if not isinstance(data, (bytes, str)):
        raise TypeError(f"atomic_write takes bytes or str, not {type(data).__name__}")
    path = Path(path)
    base, parts = _write_root(path, root)
    payload = data.encode("utf-8") if isinstance(data, str) else data
    dfd = _open_dir(base, parts[:-1], create=True, verb="write")
    name = parts[-1]
    tmp = f".{name}.{os.getpid()}.{id(payload):x}.tmp"
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC,
                     0o644, dir_fd=dfd)
        try:
            view = memoryview(payload)
            while view:
                view = view[os.write(fd, view):]
            if fsync:
                os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, name, src_dir_fd=dfd, dst_dir_fd=dfd)
    except BaseException as exc:
        try:
            os.unlink(tmp, dir_fd=dfd)
        except OSError:
            pass
        if isinstance(exc, OSError):  # what a "disk full" line names (infra/errors.py)
            exc.visphy_path, exc.visphy_needed = str(path), len(payload)
        raise
    finally:
        os.close(dfd)
    return path


def append_line(path: str | Path, data: bytes | str, root: str | Path | None = None, *,
                fsync: bool = False) -> None:
    """Append ``data`` to ``path`` in one ``write`` (created, mode 0o644, when missing), never
    through a link and only to a regular, singly linked file of this user: the file this run
    (or an earlier visphy process) created. Anything else raises `ForeignFileError`."""
    path = Path(path)
    base, parts = _write_root(path, root)
    payload = data.encode("utf-8") if isinstance(data, str) else data
    dfd = _open_dir(base, parts[:-1], create=True, verb="append to")
    try:
        try:
            fd = os.open(parts[-1], os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_NOFOLLOW
                         | os.O_NONBLOCK | os.O_CLOEXEC, 0o644, dir_fd=dfd)
        except OSError as exc:
            raise _why_not_opened(dfd, parts[-1], path, exc, "append to") from None
    finally:
        os.close(dfd)
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode) or st.st_nlink != 1 or st.st_uid != os.geteuid():
            raise ForeignFileError(f"refused to append to {path}: it is not a regular file "
                                   "created by visphy (a special file, a hard link or another "
                                   "user's file)")
        os.write(fd, payload)
        if fsync:
            os.fsync(fd)
    finally:
        os.close(fd)


# ------------------------------------------------------------------ checking a whole tree
#: The size-cap kind of a file in a foreign tree, by suffix (`LIMITS`).
KIND_BY_SUFFIX = {".txt": "text", ".md": "text", ".log": "text", ".html": "reply",
                  ".py": "reply", ".yaml": "text", ".json": "json", ".jsonl": "jsonl",
                  ".mp4": "video", ".webm": "video", ".png": "image", ".jpg": "image",
                  ".npz": "array", ".npy": "array", ".parquet": "jsonl"}


def kind_for(name: str) -> str:
    """The size-cap kind of a file named ``name`` (`KIND_BY_SUFFIX`, else ``"any"``)."""
    return KIND_BY_SUFFIX.get(os.path.splitext(name)[1].lower(), "any")


def scan_tree(root: str | Path, *, max_entries: int = 1_000_000) -> dict[str, str]:
    """Every entry below ``root`` that visphy refuses to read, as {relative posix path: why}:
    symbolic links (never followed, whatever they point at), FIFOs, sockets and devices, and
    regular files over the size cap of their kind (`kind_for`). Walked without following
    links; an empty dict means every file below ``root`` may be read by path. Checking a tree
    once when a command takes it (a run directory to re-score, merge, report or rate; a
    dataset folder) makes every later read of it safe as long as nobody changes the tree
    meanwhile; reads of trees that another party may change use `read_bytes` and friends."""
    root = Path(root)
    problems: dict[str, str] = {}
    seen = 0
    fd = _open_dir(root, ())
    stack: list[tuple[int, str]] = [(fd, "")]
    try:
        while stack:
            dfd, rel = stack.pop()
            try:
                with os.scandir(dfd) as it:
                    entries = sorted(it, key=lambda e: e.name)
                for entry in entries:
                    seen += 1
                    if seen > max_entries:
                        problems[rel or "."] = f"the tree has over {max_entries} entries"
                        return problems
                    sub = f"{rel}/{entry.name}" if rel else entry.name
                    st = entry.stat(follow_symlinks=False)
                    if stat.S_ISLNK(st.st_mode):
                        problems[sub] = "a symbolic link (links are never followed in a tree " \
                                        "visphy did not write)"
                    elif stat.S_ISDIR(st.st_mode):
                        try:
                            stack.append((os.open(entry.name, _DIR_FLAGS, dir_fd=dfd), sub))
                        except OSError as exc:
                            problems[sub] = f"a directory that cannot be opened ({exc.strerror})"
                    elif not stat.S_ISREG(st.st_mode):
                        problems[sub] = "not a regular file"
                    else:
                        kind = kind_for(entry.name)
                        if st.st_size > LIMITS[kind]:
                            problems[sub] = (f"{st.st_size} bytes, over the {LIMITS[kind]}-byte "
                                             f"limit for a {kind} file")
            finally:
                os.close(dfd)
    finally:
        for dfd, _ in stack:
            os.close(dfd)
    return problems


def refuse_tree(root: str | Path, what: str) -> None:
    """`ForeignFileError` naming the first entry `scan_tree` refuses under ``root`` (and how
    many there are); nothing when the whole tree may be read. ``what`` names the tree in the
    message (e.g. ``"run directory"``)."""
    problems = scan_tree(root)
    if problems:
        first = sorted(problems)[0]
        more = f" (and {len(problems) - 1} more)" if len(problems) > 1 else ""
        raise ForeignFileError(f"refused to read the {what} {root}: {Path(root) / first} is "
                               f"{problems[first]}{more}")
