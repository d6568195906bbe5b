"""The one writer of every file the toolbox produces: atomic, alone or as a set.

Every output (JSON, PNG, CSV, TOML, C sources, reports, recordings) is written to a
temporary file in the destination's folder, flushed to disk (``fsync``) and renamed
over the destination (``os.replace``, atomic on POSIX and Windows). A reader therefore
sees the old file or the new one, never a truncated mix; on any failure (full disk,
permission, interrupt) the temporary file is removed and the previous file is left
as it was. Errors name the user's path, never the temporary one.

A *set* of files (an experiment's TOML + CSV, a simulation's truth files) is written
by :func:`atomic_write_set`: every member is first written completely to its own
temporary file; only then are they renamed into place, the last member (the one a
reader opens first, e.g. the TOML) last. A kill between the renames can leave new
data beside an old manifest; the experiment format detects that case from the CSV
checksum the TOML carries (see ``experiment_io``).
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import IO, Union

from .errors import OutputError

__all__ = ["Content", "atomic_write", "atomic_write_set", "atomic_open", "check_writable", "refuse_overwriting"]

#: What a file's content may be: text, bytes, or an iterable of text/bytes chunks
#: (written one after another, so a long CSV never sits in memory whole).
Content = Union[str, bytes, bytearray, memoryview, Iterable[Union[str, bytes]]]


def _reason(exc: OSError) -> str:
    return " ".join(str(exc.strerror or exc).split())


def _error(path: Path, exc: OSError, what: str = "cannot write") -> OutputError:
    return OutputError(f"{path}: {what}: {_reason(exc)}", path=str(path))


def _temporary_beside(target: Path, suffix: str) -> tuple[int, str]:
    """Open a temporary file in ``target``'s folder (created if missing): how every output starts."""
    if target.is_dir():
        raise OutputError(f"{target}: is a directory; give a file name", path=str(target))
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        return tempfile.mkstemp(dir=target.parent, prefix=f".{target.name}.", suffix=suffix)
    except OSError as exc:
        raise _error(target, exc) from None


def check_writable(path: str | os.PathLike[str]) -> Path:
    """Check, before any work is done, that ``path`` can be written atomically.

    Parameters
    ----------
    path : str or os.PathLike
        The output file. Missing parent folders are created.

    Returns
    -------
    pathlib.Path
        The path.

    Raises
    ------
    OutputError
        If the path is an existing directory, or its folder cannot be created or
        written (a probe temporary file is created and removed).
    """
    target = Path(path)
    fd, tmp = _temporary_beside(target, ".probe")
    os.close(fd)
    _unlink_quietly(tmp)
    return target


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


def _write_temporary(target: Path, content: Content) -> str:
    """Write ``content`` to a fsynced temporary file beside ``target``; return its name."""
    fd, tmp = _temporary_beside(target, ".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            for chunk in _chunks(content):
                fh.write(chunk)
            fh.flush()
            os.fsync(fh.fileno())
        os.chmod(tmp, _mode_for(target))
    except OSError as exc:
        _unlink_quietly(tmp)
        raise _error(target, exc) from None
    except BaseException:
        _unlink_quietly(tmp)
        raise
    return tmp


def atomic_write(path: str | os.PathLike[str], content: Content) -> Path:
    """Write one file atomically.

    Parameters
    ----------
    path : str or os.PathLike
        The destination; missing folders are created.
    content : str, bytes or iterable of str/bytes
        The file's content; text is encoded as UTF-8 and written as given (no newline
        translation). An iterable is consumed chunk by chunk.

    Returns
    -------
    pathlib.Path
        The destination.

    Raises
    ------
    OutputError
        If the file cannot be written (the message names ``path``); the previous file
        is intact and no temporary file is left behind.
    """
    target = Path(path)
    tmp = _write_temporary(target, content)
    try:
        os.replace(tmp, target)
    except OSError as exc:
        _unlink_quietly(tmp)
        raise _error(target, exc) from None
    except BaseException:
        _unlink_quietly(tmp)
        raise
    _fsync_dir(target.parent)
    return target


def atomic_write_set(files: Mapping[str | os.PathLike[str], Content]) -> list[Path]:
    """Write several files as a set: all contents land on disk before any is replaced.

    Parameters
    ----------
    files : Mapping[path, content]
        Destinations and their contents (as :func:`atomic_write`), in rename order:
        put the file readers open first (the manifest, e.g. an experiment's TOML) last.

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
    targets = [Path(p) for p in files]
    if len({t.resolve() for t in targets}) != len(targets):
        raise OutputError("the same output path is named twice in one set: "
                          + ", ".join(str(t) for t in targets), path=str(targets[0]))
    temps: list[str] = []
    try:
        for target, content in zip(targets, files.values()):
            temps.append(_write_temporary(target, content))
        for i, (target, tmp) in enumerate(zip(targets, temps)):
            try:
                os.replace(tmp, target)
            except OSError as exc:
                raise _error(target, exc) from None
            temps[i] = None  # type: ignore[call-overload]
    finally:
        for tmp in temps:
            _unlink_quietly(tmp)
    for folder in {t.parent for t in targets}:
        _fsync_dir(folder)
    return targets


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike[str]) -> Iterator[IO[bytes]]:
    """A binary file handle whose content replaces ``path`` atomically on a clean exit.

    For writers that want a file object (``matplotlib``'s ``savefig``, ``json.dump``).

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
    target = Path(path)
    fd, tmp = _temporary_beside(target, ".tmp")
    try:
        with os.fdopen(fd, "wb") as fh:
            try:
                yield fh
                fh.flush()
                os.fsync(fh.fileno())
            except OSError as exc:
                raise _error(target, exc) from None
        os.chmod(tmp, _mode_for(target))
        os.replace(tmp, target)
    except OSError as exc:
        _unlink_quietly(tmp)
        if isinstance(exc, OutputError):
            raise
        raise _error(target, exc) from None
    except BaseException:
        _unlink_quietly(tmp)
        raise
    _fsync_dir(target.parent)


def refuse_overwriting(outputs: Iterable[str | os.PathLike[str]],
                       inputs: Iterable[str | os.PathLike[str]]) -> None:
    """Raise before any work if an output would replace one of the inputs of the same command.

    Parameters
    ----------
    outputs : iterable of path
        Files the command will write.
    inputs : iterable of path
        Files the command reads.

    Raises
    ------
    OutputError
        Naming the output and the input it would overwrite.
    """
    sources = {}
    for p in inputs:
        with contextlib.suppress(OSError, ValueError):
            sources[Path(p).resolve()] = Path(p)
    for out in outputs:
        try:
            resolved = Path(out).resolve()
        except (OSError, ValueError):
            continue
        if resolved in sources:
            raise OutputError(f"{out}: would overwrite the input {sources[resolved]}; "
                              "choose another output name", path=str(out))
