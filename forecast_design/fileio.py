"""The one writer of every file the toolbox produces: atomic, alone or as a set.

Every output (JSON, PNG, CSV, TOML, C sources, reports, recordings) is written to a
temporary file in the destination's folder, flushed to disk (``fsync``) and renamed
over the destination (``os.replace``, atomic on POSIX and Windows). A reader therefore
sees the old file or the new one, never a truncated mix; on any failure (full disk,
permission, interrupt) the temporary file is removed and the previous file is left
as it was. Errors name the user's path, never the temporary one.

What the destination is decides how it is written (:func:`output_kind`):

* a regular file or a missing path: replaced atomically as above;
* a symbolic link: followed to its target, and the target is replaced atomically (the
  link stays a link);
* a character device (``/dev/null``, a terminal), a FIFO, or a descriptor of this process
  (``/dev/stdout``, ``/dev/fd/N``, ``/proc/self/fd/N``): written *through*, as a shell
  redirection would (no atomicity is possible there; the device node is never replaced);
* anything else (a directory, a socket, a block device, a symlink loop): refused in one line.

A *set* of files (an experiment's TOML + CSV, a simulation's truth files) is written
by :func:`atomic_write_set`: every member is first written completely to its own
temporary file; only then are they renamed into place, the last member (the one a
reader opens first, e.g. the TOML) last. A kill between the renames can leave new
data beside an old manifest; the experiment format detects that case from the CSV
checksum the TOML carries (see ``experiment_io``). A set cannot go to a device.

A *folder* of files that belong together (a benchmark's results, a firmware project) is
written by :func:`staged_set`: the files are written into a fresh staging folder, then the
folder's manifest (``MANIFEST.sha256``, the ``sha256sum`` format) is removed, the files are
renamed into place and the new manifest, listing every member with its SHA-256, is written
last. :func:`verify_manifest` is the readers' check: a folder without its manifest, or with a
member that does not match it, is an interrupted write, never a set.

Temporary names carry this machine's tag and the writing process's id
(``.NAME.~HOST-PID-XXXXXXXX.tmp``); the first write into a folder removes the temporaries of
processes of this machine that no longer run (an interrupted or killed run), never those of a
live writer.

Inside :func:`guard_inputs` (every CLI command runs in it), the files a command has read
(:func:`note_input`) cannot be written: an output that resolves to an input (same file, also
through a symlink or a hard link) is refused in one line.
"""

from __future__ import annotations

import contextlib
import contextvars
import errno
import hashlib
import os
import re
import shutil
import socket
import stat
import sys
import tempfile
import time
import zlib
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Union

from .errors import OutputError

__all__ = ["Content", "atomic_write", "atomic_write_set", "atomic_open", "check_writable", "refuse_overwriting",
           "output_kind", "remove_stale_temporaries", "guard_inputs", "note_input", "staged_set",
           "verify_manifest", "MANIFEST", "FIFO_WAIT_S", "MAX_NAME_BYTES"]

#: What a file's content may be: text, bytes, or an iterable of text/bytes chunks
#: (written one after another, so a long CSV never sits in memory whole).
Content = Union[str, bytes, bytearray, memoryview, Iterable[Union[str, bytes]]]

#: The manifest of a folder written by :func:`staged_set` (``sha256sum --check`` reads it).
MANIFEST = "MANIFEST.sha256"
#: How long a write to a FIFO waits for a reader to open it [s] (then a one-line error, not a hang).
FIFO_WAIT_S = 30.0
#: Longest file name a folder holds (POSIX ``NAME_MAX``) [bytes]; temporary names stay within it.
MAX_NAME_BYTES = 255
_STEM_BYTES = 200          # bytes of the destination's name kept in a temporary name
_MAX_LINKS = 40            # symbolic links followed before a path counts as a loop (Linux's own limit)
_HOST = f"{zlib.crc32(socket.gethostname().encode('utf-8', 'replace')):08x}"
_TEMP_NAME = re.compile(r"^\..*\.~([0-9a-f]{8})-([0-9]+)-[a-z0-9_]{8}\.(tmp|probe|tmpdir)$", re.S)
# a descriptor of a process: /proc/<pid|self|thread-self>[/task/<tid>]/fd/N (also /dev/fd/N, which links there)
_FD_PATH = re.compile(r"^/proc/(self|thread-self|[0-9]+)(?:/task/[0-9]+)?/fd/([0-9]+)$")


def _reason(exc: OSError) -> str:
    return " ".join(str(exc.strerror or exc).split())


def _error(path: Path | str, exc: OSError, what: str = "cannot write") -> OutputError:
    return OutputError(f"{path}: {what}: {_reason(exc)}", path=str(path))


# --- what a destination is -------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class _Destination:
    """Where an output goes: the file to replace atomically, or a stream written through."""

    path: Path            # the user's path (every message names it)
    target: Path          # the regular (or missing) file to replace, or the stream to open
    stream: bool          # write through (device, FIFO, descriptor)
    fd: int | None        # a descriptor of this process to write to (/dev/stdout, /proc/self/fd/N)


def _own_pid(text: str) -> bool:
    return text in ("self", "thread-self") or text == str(os.getpid())


def _destination(path: str | os.PathLike[str]) -> _Destination:
    """Follow ``path``'s symbolic links one by one (so a descriptor link is seen) and classify the end."""
    user = Path(path)
    try:
        current = os.path.abspath(os.fspath(user))
    except (TypeError, ValueError) as exc:
        raise OutputError(f"{user}: not a usable output path ({exc})", path=str(user)) from None
    for _ in range(_MAX_LINKS):
        parent, name = os.path.split(current)
        current = os.path.join(os.path.realpath(parent), name)
        match = _FD_PATH.match(current)
        if match:
            own = _own_pid(match.group(1))
            return _Destination(user, Path(current), True, int(match.group(2)) if own else None)
        try:
            info = os.lstat(current)
        except FileNotFoundError:
            return _Destination(user, Path(current), False, None)     # a new file (also at a dangling link's end)
        except OSError as exc:
            raise _error(user, exc) from None
        if stat.S_ISLNK(info.st_mode):
            current = os.path.join(os.path.dirname(current), os.readlink(current))
            continue
        if stat.S_ISREG(info.st_mode):
            return _Destination(user, Path(current), False, None)
        if stat.S_ISCHR(info.st_mode) or stat.S_ISFIFO(info.st_mode):
            return _Destination(user, Path(current), True, None)
        if stat.S_ISDIR(info.st_mode):
            raise OutputError(f"{user}: is a directory; give a file name", path=str(user))
        kind = "a socket" if stat.S_ISSOCK(info.st_mode) else "a block device" if stat.S_ISBLK(info.st_mode) \
            else "not a regular file"
        raise OutputError(f"{user}: is {kind}; an output must be a regular file, a FIFO or a character device",
                          path=str(user))
    raise OutputError(f"{user}: too many levels of symbolic links (a loop?)", path=str(user))


def output_kind(path: str | os.PathLike[str]) -> str:
    """How :func:`atomic_write` would write ``path``: ``"file"`` (replaced atomically) or ``"stream"``.

    Parameters
    ----------
    path : str or os.PathLike
        The destination.

    Returns
    -------
    str
        ``"file"`` for a regular file, a missing path or a symlink to either (its target is
        replaced); ``"stream"`` for a character device, a FIFO or a descriptor of this process
        (written through).

    Raises
    ------
    OutputError
        For a directory, socket, block device or symlink loop (one line naming ``path``).
    """
    return "stream" if _destination(path).stream else "file"


def _open_stream(dest: _Destination) -> int:
    """A descriptor to write ``dest`` through (a dup of our own, or the device/FIFO opened)."""
    if dest.fd is not None:
        for stream in (sys.stdout, sys.stderr):    # keep the order of what was printed before
            with contextlib.suppress(Exception):
                if stream.fileno() == dest.fd:
                    stream.flush()
        try:
            return os.dup(dest.fd)
        except OSError as exc:
            raise _error(dest.path, exc) from None
    flags = os.O_WRONLY | getattr(os, "O_NOCTTY", 0) | getattr(os, "O_CLOEXEC", 0)
    try:
        if not stat.S_ISFIFO(os.stat(dest.target).st_mode):
            return os.open(dest.target, flags)
        # a FIFO: wait (bounded) for a reader instead of blocking forever in open()
        deadline = time.monotonic() + FIFO_WAIT_S
        while True:
            try:
                fd = os.open(dest.target, flags | os.O_NONBLOCK)
                break
            except OSError as exc:
                if exc.errno != errno.ENXIO:
                    raise
                if time.monotonic() > deadline:
                    raise OutputError(f"{dest.path}: no reader opened this FIFO within {FIFO_WAIT_S:g} s",
                                      path=str(dest.path)) from None
                time.sleep(0.05)
        os.set_blocking(fd, True)
        return fd
    except OutputError:
        raise
    except OSError as exc:
        raise _error(dest.path, exc) from None


def _write_through(dest: _Destination, content: Content) -> None:
    fd = _open_stream(dest)
    try:
        with os.fdopen(fd, "wb", closefd=True) as fh:
            for chunk in _chunks(content):
                fh.write(chunk)
            fh.flush()
    except BrokenPipeError:
        raise                      # the reader went away: the CLI stops quietly, as for stdout
    except OutputError:
        raise
    except OSError as exc:
        raise _error(dest.path, exc) from None


# --- inputs a command must not overwrite ---------------------------------------------------------------------------

_INPUTS: contextvars.ContextVar[dict | None] = contextvars.ContextVar("forecast_design_inputs", default=None)


def _identity(path: str | os.PathLike[str]) -> tuple[int, int] | None:
    with contextlib.suppress(OSError, ValueError, TypeError):
        info = os.stat(path)
        if stat.S_ISREG(info.st_mode):
            return info.st_dev, info.st_ino
    return None


@contextlib.contextmanager
def guard_inputs() -> Iterator[None]:
    """Within the block, no output may replace a file read through :func:`note_input`.

    The CLI runs every command inside it. Outside it (library use, notebooks) nothing is
    recorded: saving over a file loaded earlier stays possible there.

    Yields
    ------
    None
    """
    token = _INPUTS.set({})
    try:
        yield
    finally:
        _INPUTS.reset(token)


def note_input(path: str | os.PathLike[str]) -> None:
    """Record that the running command reads ``path`` (every reader of the toolbox calls it).

    Parameters
    ----------
    path : str or os.PathLike
        A file read; only regular files are recorded (by device and inode, so a symlink or a
        hard link to it is the same input).
    """
    inputs = _INPUTS.get()
    if inputs is None:
        return
    ident = _identity(path)
    if ident is not None:
        inputs.setdefault(ident, os.fspath(path))


def _refuse_input(user: Path, target: Path) -> None:
    inputs = _INPUTS.get()
    if not inputs:
        return
    ident = _identity(target)
    if ident is not None and ident in inputs:
        raise OutputError(f"{user}: would overwrite the input {inputs[ident]}; choose another output name",
                          path=str(user))


def refuse_overwriting(outputs: Iterable[str | os.PathLike[str] | None],
                       inputs: Iterable[str | os.PathLike[str] | None]) -> None:
    """Raise before any work if an output would replace one of the inputs of the same command.

    Files are compared by what they resolve to (device and inode of an existing file, so
    symlinks and hard links count; the resolved path of a missing output).

    Parameters
    ----------
    outputs : iterable of path or None
        Files the command will write (None entries are skipped; a stream such as
        ``/dev/stdout`` never replaces a file).
    inputs : iterable of path or None
        Files the command reads (None entries are skipped).

    Raises
    ------
    OutputError
        Naming the output and the input it would overwrite.
    """
    sources: dict[object, str] = {}
    for p in inputs:
        if p is None:
            continue
        ident = _identity(p)
        if ident is not None:
            sources[ident] = os.fspath(p)
        with contextlib.suppress(OSError, ValueError, TypeError, RuntimeError):   # RuntimeError: a symlink loop
            sources.setdefault(Path(p).resolve(), os.fspath(p))
    for out in outputs:
        if out is None or os.fspath(out) == "-":
            continue
        try:
            dest = _destination(out)
        except OutputError:
            continue                   # the writer itself refuses it, with its own message
        if dest.stream:
            continue
        for key in (_identity(dest.target), dest.target):
            if key is not None and key in sources:
                raise OutputError(f"{out}: would overwrite the input {sources[key]}; choose another output name",
                                  path=os.fspath(out))


# --- temporaries ---------------------------------------------------------------------------------------------------

_CLEANED: set[str] = set()


def _temp_prefix(name: str) -> str:
    stem = os.fsdecode(os.fsencode(name)[:_STEM_BYTES])      # long names: the temporary still fits NAME_MAX
    return f".{stem}.~{_HOST}-{os.getpid()}-"


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OSError, OverflowError):
        return True
    return True


def remove_stale_temporaries(folder: str | os.PathLike[str]) -> list[Path]:
    """Remove the temporaries that killed or interrupted writers of this machine left in ``folder``.

    Parameters
    ----------
    folder : str or os.PathLike
        A folder outputs are written to (not searched recursively).

    Returns
    -------
    list of pathlib.Path
        What was removed: temporary files and staging folders whose writing process (named in
        the temporary's name, with this machine's tag) no longer runs. A live writer's
        temporaries and other machines' are left alone.
    """
    removed = []
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return removed
    for entry in entries:
        match = _TEMP_NAME.match(entry.name)
        if match is None or match.group(1) != _HOST or _alive(int(match.group(2))):
            continue
        with contextlib.suppress(OSError):
            if match.group(3) == "tmpdir" and entry.is_dir(follow_symlinks=False):
                shutil.rmtree(entry.path)
            else:
                os.unlink(entry.path)
            removed.append(Path(entry.path))
    return removed


def _clean_once(folder: Path) -> None:
    key = os.path.abspath(folder)
    if key not in _CLEANED:
        _CLEANED.add(key)
        remove_stale_temporaries(folder)


def _temporary_beside(target: Path, suffix: str, user: Path | None = None) -> tuple[int, str]:
    """Open a temporary file in ``target``'s folder (created if missing): how every output starts."""
    user = target if user is None else user
    if target.is_dir():
        raise OutputError(f"{user}: is a directory; give a file name", path=str(user))
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        _clean_once(target.parent)
        return tempfile.mkstemp(dir=target.parent, prefix=_temp_prefix(target.name), suffix=suffix)
    except OSError as exc:
        raise _error(user, exc) from None


def check_writable(path: str | os.PathLike[str], *, stream_ok: bool = True) -> Path:
    """Check, before any work is done, that ``path`` can be written.

    Parameters
    ----------
    path : str or os.PathLike
        The output file. Missing parent folders are created.
    stream_ok : bool
        Whether a device or FIFO (written through) is acceptable; False for the first file of a
        set (an experiment's TOML, whose CSV and truth files go beside it).

    Returns
    -------
    pathlib.Path
        The path.

    Raises
    ------
    OutputError
        If the path is a directory, socket, block device or symlink loop, a device where
        ``stream_ok`` is False, or its folder cannot be created or written (a probe temporary
        file is created and removed).
    """
    dest = _destination(path)
    if dest.stream:
        if not stream_ok:
            raise OutputError(f"{dest.path}: is a device or FIFO; this output is a set of files (the names "
                              "beside it are derived from it), give a file name", path=str(dest.path))
        return dest.path
    _refuse_input(dest.path, dest.target)
    fd, tmp = _temporary_beside(dest.target, ".probe", dest.path)
    os.close(fd)
    _unlink_quietly(tmp)
    return dest.path


def _chunks(content: Content) -> Iterator[bytes]:
    if isinstance(content, str):
        yield content.encode("utf-8")
    elif isinstance(content, (bytes, bytearray, memoryview)):
        yield bytes(content)
    else:
        for chunk in content:
            yield chunk.encode("utf-8") if isinstance(chunk, str) else bytes(chunk)


def _mode_for(target: Path) -> int:
    # mkstemp creates 0600; keep an existing file's permissions, else the umask default.
    try:
        return target.stat().st_mode & 0o777
    except OSError:
        umask = os.umask(0)
        os.umask(umask)
        return 0o666 & ~umask


def _fsync_dir(folder: Path) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return  # not supported (Windows) or not permitted: the rename is still atomic
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _unlink_quietly(tmp: str | None) -> None:
    if tmp is not None:
        with contextlib.suppress(OSError):
            os.unlink(tmp)


def _write_temporary(dest: _Destination, content: Content) -> str:
    """Write ``content`` to a fsynced temporary file beside ``dest.target``; return its name."""
    fd, tmp = _temporary_beside(dest.target, ".tmp", dest.path)
    try:
        with os.fdopen(fd, "wb") as fh:
            for chunk in _chunks(content):
                fh.write(chunk)
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, _mode_for(dest.target))
    except OSError as exc:
        _unlink_quietly(tmp)
        raise _error(dest.path, exc) from None
    except BaseException:
        _unlink_quietly(tmp)
        raise
    return tmp


def atomic_write(path: str | os.PathLike[str], content: Content) -> Path:
    """Write one file atomically (or through, to a device, FIFO or descriptor).

    Parameters
    ----------
    path : str or os.PathLike
        The destination; missing folders are created. A symlink is followed and its target
        replaced; a character device, a FIFO or ``/dev/stdout`` is written through.
    content : str, bytes or iterable of str/bytes
        The file's content; text is encoded as UTF-8 and written as given (no newline
        translation). An iterable is consumed chunk by chunk.

    Returns
    -------
    pathlib.Path
        The destination, as given.

    Raises
    ------
    OutputError
        If the file cannot be written (the message names ``path``); the previous file
        is intact and no temporary file is left behind.
    """
    dest = _destination(path)
    if dest.stream:
        _write_through(dest, content)
        return dest.path
    _refuse_input(dest.path, dest.target)
    tmp = _write_temporary(dest, content)
    try:
        os.replace(tmp, dest.target)
    except OSError as exc:
        _unlink_quietly(tmp)
        raise _error(dest.path, exc) from None
    except BaseException:
        _unlink_quietly(tmp)
        raise
    _fsync_dir(dest.target.parent)
    return dest.path


def atomic_write_set(files: Mapping[str | os.PathLike[str], Content]) -> list[Path]:
    """Write several files as a set: all contents land on disk before any is replaced.

    Parameters
    ----------
    files : Mapping[path, content]
        Destinations and their contents (as :func:`atomic_write`), in rename order:
        put the file readers open first (the manifest, e.g. an experiment's TOML) last.
        Every destination must be a regular file, a missing path or a symlink to one: a
        set is never written to a device or FIFO.

    Returns
    -------
    list[pathlib.Path]
        The destinations, in the order given.

    Raises
    ------
    OutputError
        If any member cannot be written; then no destination has been touched and every
        temporary file is removed. A failure during the renames (rare: the data are
        already on disk) names the member and leaves the members renamed so far.
    """
    dests = [_destination(p) for p in files]
    for dest in dests:
        if dest.stream:
            raise OutputError(f"{dest.path}: is a device or FIFO; a set of files ("
                              f"{', '.join(d.path.name for d in dests)}) needs regular files", path=str(dest.path))
        _refuse_input(dest.path, dest.target)
    if len({d.target for d in dests}) != len(dests):
        raise OutputError("the same output path is named twice in one set: "
                          + ", ".join(str(d.path) for d in dests), path=str(dests[0].path))
    temps: list[str | None] = []
    try:
        for dest, content in zip(dests, files.values()):
            temps.append(_write_temporary(dest, content))
        for i, (dest, tmp) in enumerate(zip(dests, temps)):
            try:
                os.replace(tmp, dest.target)
            except OSError as exc:
                raise _error(dest.path, exc) from None
            temps[i] = None
    finally:
        for tmp in temps:
            _unlink_quietly(tmp)
    for folder in {d.target.parent for d in dests}:
        _fsync_dir(folder)
    return [d.path for d in dests]


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike[str]) -> Iterator[IO[bytes]]:
    """A binary file handle whose content replaces ``path`` atomically on a clean exit.

    For writers that want a file object (``matplotlib``'s ``savefig``, ``json.dump``). A
    device, FIFO or descriptor is written through (what the block wrote stays written).

    Parameters
    ----------
    path : str or os.PathLike
        The destination; missing folders are created.

    Yields
    ------
    IO[bytes]
        The temporary file, opened for binary writing.

    Raises
    ------
    OutputError
        If the file cannot be written; the previous file is intact. An exception raised
        inside the block discards the temporary file and propagates unchanged.
    """
    dest = _destination(path)
    if dest.stream:
        fd = _open_stream(dest)
        try:
            with os.fdopen(fd, "wb") as fh:
                yield fh
        except (OutputError, BrokenPipeError):
            raise
        except OSError as exc:
            raise _error(dest.path, exc) from None
        return
    _refuse_input(dest.path, dest.target)
    fd, tmp = _temporary_beside(dest.target, ".tmp", dest.path)
    try:
        with os.fdopen(fd, "wb") as fh:
            try:
                yield fh
                fh.flush()
                os.fsync(fh.fileno())
            except OSError as exc:
                if isinstance(exc, OutputError):
                    raise
                raise _error(dest.path, exc) from None
        os.chmod(tmp, _mode_for(dest.target))
        os.replace(tmp, dest.target)
    except OSError as exc:
        _unlink_quietly(tmp)
        if isinstance(exc, OutputError):
            raise
        raise _error(dest.path, exc) from None
    except BaseException:
        _unlink_quietly(tmp)
        raise
    _fsync_dir(dest.target.parent)


# --- folders of files that belong together ---------------------------------------------------------------------------


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


_MANIFEST_LINE = re.compile(r"^([0-9a-f]{64}) [ *](.+)$")


def _read_manifest(path: Path) -> dict[str, str] | None:
    """``{name: sha256}`` of a manifest, None if it is missing; OutputError if it is not one."""
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        return None
    except (OSError, UnicodeDecodeError) as exc:
        raise OutputError(f"{path}: cannot read the manifest: {exc}", path=str(path)) from None
    out = {}
    for lineno, line in enumerate(text.splitlines(), 1):
        match = _MANIFEST_LINE.match(line)
        if match is None or "/" in match.group(2) or match.group(2) in (".", ".."):
            raise OutputError(f"{path}: line {lineno} is not a manifest line (SHA256  NAME)", path=str(path))
        out[match.group(2)] = match.group(1)
    return out


def verify_manifest(folder: str | os.PathLike[str], manifest: str = MANIFEST) -> dict[str, Path]:
    """Check that ``folder`` holds one complete set written by :func:`staged_set`.

    Parameters
    ----------
    folder : str or os.PathLike
        The folder.
    manifest : str
        The manifest's file name in it.

    Returns
    -------
    dict of str to pathlib.Path
        Every member named by the manifest, each checked against its SHA-256.

    Raises
    ------
    OutputError
        One line: the manifest is missing (a write was interrupted, or the folder was never
        written), unreadable, or a member is missing or differs from it.
    """
    root = Path(folder)
    listed = _read_manifest(root / manifest)
    if listed is None:
        raise OutputError(f"{root}: no {manifest}: not a complete result set (a write was interrupted, or this "
                          "folder was not written by forecast-design); write it again", path=str(root))
    members = {}
    for name, digest in listed.items():
        path = root / name
        try:
            actual = _sha256(path)
        except OSError as exc:
            raise OutputError(f"{path}: listed in {manifest} but {_reason(exc)}: an incomplete set; write it again",
                              path=str(path)) from None
        if actual != digest:
            raise OutputError(f"{path}: differs from {manifest} (sha256 {actual[:12]}..., listed {digest[:12]}...): "
                              "an interrupted write or an edit", path=str(path))
        members[name] = path
    return members


@contextlib.contextmanager
def staged_set(folder: str | os.PathLike[str], *, manifest: str = MANIFEST) -> Iterator[Path]:
    """Write a folder's set of files so that no reader ever sees old and new members mixed.

    The block writes the members (plain files, any writer of this module) into the yielded
    staging folder, which lies inside ``folder``. On a clean exit the old manifest is removed,
    the members are renamed into ``folder``, members of the previous set that the new one lacks
    are removed, and the new manifest is written last. An exception inside the block leaves
    ``folder`` as it was. A kill leaves either the old set with its manifest, or no manifest
    (:func:`verify_manifest` refuses the folder) and a staging folder that the next write
    into ``folder`` removes.

    Parameters
    ----------
    folder : str or os.PathLike
        The result folder (created if missing); other files in it (e.g. a cache folder) are
        left alone.
    manifest : str
        The manifest's file name.

    Yields
    ------
    pathlib.Path
        The staging folder to write the members into (flat: no sub-folders).

    Raises
    ------
    OutputError
        If the folder cannot be written, a member would replace an input of the command or a
        directory, or the staging folder holds a sub-folder.
    """
    root = Path(folder)
    if root.exists() and not root.is_dir():
        raise OutputError(f"{root}: is not a folder; give a folder name", path=str(root))
    try:
        root.mkdir(parents=True, exist_ok=True)
        _clean_once(root)
        staging = Path(tempfile.mkdtemp(dir=root, prefix=_temp_prefix("set"), suffix=".tmpdir"))
    except OSError as exc:
        raise _error(root, exc) from None
    try:
        yield staging
        _commit(root, staging, manifest)
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def _commit(root: Path, staging: Path, manifest: str) -> None:
    names = sorted(entry.name for entry in os.scandir(staging))
    pending = root / f".{manifest}.pending"
    for name in names:
        if name in (manifest, pending.name):
            raise OutputError(f"{root / name}: is the manifest's name; a member cannot use it", path=str(root / name))
        if (staging / name).is_dir() or (root / name).is_dir():
            raise OutputError(f"{root / name}: a set holds files only, not folders", path=str(root / name))
        _refuse_input(root / name, root / name)
    digests = {name: _sha256(staging / name) for name in names}
    # every name that may be in the folder from an earlier set, also from writes killed half-way
    # (their names stay in the pending list until a write completes): members the new set lacks go
    earlier: set[str] = set()
    for listing in (root / manifest, pending):
        with contextlib.suppress(OutputError):
            earlier |= set(_read_manifest(listing) or {})
    atomic_write(pending, "".join(f"{'0' * 64}  {name}\n" for name in sorted(earlier | set(names))))
    try:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(root / manifest)      # from here until the end, readers see "no complete set"
        _fsync_dir(root)
        for name in names:
            os.replace(staging / name, root / name)
        for name in earlier - set(names):
            with contextlib.suppress(OSError):
                if (root / name).is_file():
                    os.unlink(root / name)
        _fsync_dir(root)
    except OSError as exc:
        raise _error(root, exc) from None
    atomic_write(root / manifest, "".join(f"{digests[name]}  {name}\n" for name in names))
    with contextlib.suppress(OSError):
        os.unlink(pending)
