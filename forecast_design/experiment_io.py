"""Reading and writing the files of the forecast-experiment/1 format (TOML + CSV).

The in-memory experiment (``Experiment``, ``Signals``) and the rules on sample values
live in :mod:`forecast_design.experiment`; this module turns files into validated
tables and back, and is the one CSV reader of the toolbox (experiment logs and the
plain ``--csv`` axis logs of ``identify``).

Reading. Files must be regular files (a FIFO, a device or a directory is refused
before anything is read, so nothing hangs or fills memory). A CSV is read whole
into memory once and parsed by pyarrow's columnar reader into float64 arrays; any
irregularity (a bad cell, a ragged or blank line) sends the file through a
line-by-line scan that names the first bad line, so errors stay the format's
one-line messages. Peak memory is the file's bytes plus 8 bytes per cell (about
140 bytes per sample for a six-column log written by :func:`write_experiment_files`),
linear in the number of rows. Accepted: a UTF-8 byte-order mark, LF, CRLF or CR line
ends, blanks around cells, quoted cells, blank lines at the end of the file, and
numbers as decimal or exponent literals (``nan``/``inf`` are read and then rejected
by the sample checks, naming the line). Not accepted: comment lines (the format has
none), blank lines between rows, digit separators (``5_2``), non-ASCII digits.
The ``data`` key may name any regular file, also outside the TOML's folder
(``../``, absolute paths), as the format allows.

Writing. The CSV and the TOML are written as one set through
:func:`forecast_design.fileio.atomic_write_set`: both are complete on disk before
either is renamed into place, the TOML last. The TOML ends with a comment line
``# data-crc32 = XXXXXXXX, data-bytes = N`` (a TOML comment: other readers of the
format ignore it); the loader checks it, so a CSV that does not belong to its TOML
(a save interrupted between the two renames, or a CSV edited by hand) is an error
naming both files instead of a silent mix.
"""

from __future__ import annotations

import csv
import math
import mmap
import os
import re
import stat
import tomllib
import zlib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w

from .errors import ExperimentFormatError, ParameterError
from .fileio import Content, atomic_write_set, note_input
from .controllers import controller_from_mapping
from .params import Compensator, Design, Environment, Testbed

__all__ = [
    "FORMAT",
    "REQUIRED_COLUMNS",
    "OPTIONAL_COLUMNS",
    "ExperimentFiles",
    "read_csv_table",
    "read_experiment_files",
    "parse_toml_bytes",
    "TOML_MAX_BYTES",
    "TOML_MAX_DEPTH",
    "CSV_MAX_LINE_BYTES",
    "DEFAULT_MAX_SAMPLES",
    "write_experiment_files",
]

#: The exact value of the TOML ``format`` key.
FORMAT = "forecast-experiment/1"
#: CSV columns every experiment has, in file order.
REQUIRED_COLUMNS = ("t", "tau_m", "theta", "q")
#: CSV columns the format defines but does not require.
OPTIONAL_COLUMNS = ("tau_s", "tau_r")

SPEC_COLUMNS = REQUIRED_COLUMNS + OPTIONAL_COLUMNS
TOP_LEVEL_KEYS = ("format", "description", "data", "sampling", "testbed", "environment",
                  "controller", "compensator")
_CSV_FORMAT = "%.17g"  # 17 significant digits: every float64 survives text exactly
_WRITE_CHUNK = 100_000  # rows formatted per write, bounds memory for long logs
_ECHO = 60  # at most this many characters of a file's content appear in an error
_BOM = b"\xef\xbb\xbf"
# What pyarrow's float parser accepts, so that both paths agree on every cell.
_NUMBER = re.compile(r"[ \t]*[+-]?(?:(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?"
                     r"|inf(?:inity)?|nan)[ \t]*", re.ASCII | re.IGNORECASE)
_CHECKSUM = re.compile(rb"^# data-crc32 = ([0-9a-f]{8}), data-bytes = ([0-9]+)[ \t]*\r?$", re.M)
_CHECKSUM_KEY = re.compile(rb"^[ \t]*#[ \t]*data-crc32\b", re.M)   # a line meant as the checksum, well-formed or not
#: Largest TOML file read (experiments, scenarios, environment sets, testbeds) [bytes]: checked before reading.
TOML_MAX_BYTES = 16 * 2**20
#: Deepest nesting of tables and arrays in a TOML file read [-] (the formats need 4).
TOML_MAX_DEPTH = 32
#: Longest CSV line (the header included) [bytes]: a longer one is refused before it is decoded.
CSV_MAX_LINE_BYTES = 2**16
#: Bytes a CSV cell may take on average when a file's size is checked against a row limit [bytes].
CSV_MAX_CELL_BYTES = 64
#: Most samples (CSV rows) an experiment may have when the caller states no limit [-] (the
#: longest recorded run, ``runtime.samples.MAX_RUN_SAMPLES``); each verb states its own.
DEFAULT_MAX_SAMPLES = 2**24


def one_line(text: Any) -> str:
    """``text`` with every run of white space (line breaks included) made one blank."""
    return " ".join(str(text).split())


def clip(text: Any, limit: int = _ECHO) -> str:
    """One line of at most ``limit`` characters (with an ellipsis), for echoing file content."""
    line = one_line(text)
    return line if len(line) <= limit else line[: limit - 3] + "..."


def check_rate(rate_hz: Any, *, label: str, path: str | None) -> float:
    """A sampling rate as a finite positive float [Hz]; raise naming ``label`` otherwise."""
    prefix = f"{path}: " if path else ""
    if isinstance(rate_hz, bool) or not isinstance(rate_hz, (int, float, np.integer, np.floating)):
        raise ExperimentFormatError(
            f"{prefix}{label} must be a number [Hz], got {clip(repr(rate_hz))}", path=path,
            key="sampling.rate_hz")
    rate = float(rate_hz)
    if not math.isfinite(rate) or rate <= 0.0:
        raise ExperimentFormatError(
            f"{prefix}{label} must be > 0 and finite [Hz], got {rate!r}", path=path, key="sampling.rate_hz"
        )
    return rate


def read_regular_file(path: Path, label: str, *, not_found: str | None = None,
                      unreadable: str | None = None, error_path: str | None = None,
                      error_key: str | None = None, mapped: bool = False,
                      max_bytes: int | None = None, what: str = "file") -> bytes | mmap.mmap:
    """The bytes of a regular file; FIFOs, devices and directories are refused unread.

    ``not_found`` and ``unreadable`` (with ``{reason}``) replace the default messages
    and are raised with ``error_path`` and ``error_key``. With ``mapped``, a read-only
    memory map (no copy of the file on the heap) instead of bytes. A file larger than
    ``max_bytes`` is refused before anything is read (``what`` names it in the message).
    The file is recorded as an input of the running command (:func:`~.fileio.note_input`).
    """
    try:
        info = os.stat(path)
    except (OSError, ValueError):  # ValueError: a NUL byte in the path
        info = None
    if info is not None and not stat.S_ISREG(info.st_mode):
        kind = "a directory" if stat.S_ISDIR(info.st_mode) else "not a regular file (a FIFO or device?)"
        raise ExperimentFormatError(f"{label}: {kind}; only regular files are read", path=label)
    if info is not None and max_bytes is not None and info.st_size > max_bytes:
        raise ExperimentFormatError(f"{label}: {info.st_size} bytes, more than a {what} may have "
                                    f"({max_bytes} bytes); not read", path=label)
    try:
        with open(path, "rb") as fh:
            note_input(path)
            if mapped and os.fstat(fh.fileno()).st_size > 0:
                return mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)
            data = fh.read() if max_bytes is None else fh.read(max_bytes + 1)
    except FileNotFoundError:
        if not_found is None:
            raise ExperimentFormatError(f"{label}: file not found", path=label) from None
        raise ExperimentFormatError(not_found, path=error_path, key=error_key) from None
    except (OSError, ValueError) as exc:
        reason = one_line(getattr(exc, "strerror", None) or exc)
        if unreadable is None:
            raise ExperimentFormatError(f"{label}: cannot read: {reason}", path=label) from None
        raise ExperimentFormatError(unreadable.replace("{reason}", reason), path=error_path,
                                    key=error_key) from None
    if max_bytes is not None and len(data) > max_bytes:     # it grew after the check
        raise ExperimentFormatError(f"{label}: more than a {what} may have ({max_bytes} bytes); not read",
                                    path=label)
    return data


# --- TOML -----------------------------------------------------------------------------


def _depth(doc: Any) -> int:
    """Deepest nesting of tables and arrays in a parsed TOML document (iterative: no recursion)."""
    deepest, stack = 0, [(doc, 1)]
    while stack:
        obj, level = stack.pop()
        deepest = max(deepest, level)
        if level > TOML_MAX_DEPTH:
            break
        children = obj.values() if isinstance(obj, dict) else obj if isinstance(obj, list) else ()
        stack.extend((child, level + 1) for child in children if isinstance(child, (dict, list)))
    return deepest


def parse_toml_bytes(raw: bytes, label: str) -> dict[str, Any]:
    """Parse a TOML file's bytes: UTF-8 (a byte-order mark is accepted), at most :data:`TOML_MAX_DEPTH` deep.

    Parameters
    ----------
    raw : bytes
        The file's content.
    label : str
        How errors name the file.

    Returns
    -------
    dict
        The document.

    Raises
    ------
    ExperimentFormatError
        One line naming the file: not UTF-8 (with the byte offset), a syntax error (with
        its line), or nested deeper than :data:`TOML_MAX_DEPTH`.
    """
    start = len(_BOM) if raw[:len(_BOM)] == _BOM else 0
    try:
        text = raw[start:].decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ExperimentFormatError(f"{label}: not UTF-8 text ({one_line(exc.reason)} at byte "
                                    f"{exc.start + start})", path=label) from None
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        match = re.search(r"line (\d+)", str(exc))
        raise ExperimentFormatError(
            f"{label}: TOML syntax error: {one_line(exc)}", path=label,
            key=f"line {match.group(1)}" if match else None,
        ) from None
    except RecursionError:
        doc = None
    if doc is None or _depth(doc) > TOML_MAX_DEPTH:
        raise ExperimentFormatError(f"{label}: tables or arrays nested more than {TOML_MAX_DEPTH} levels deep; "
                                    "not a file of this format", path=label)
    return doc


def read_toml(path: Path, what: str = "experiment file") -> tuple[dict[str, Any], bytes]:
    """The parsed TOML document and its raw bytes; one-line errors naming the file.

    Every TOML file the toolbox reads comes through here: regular files only, at most
    :data:`TOML_MAX_BYTES` (checked before reading), parsed by :func:`parse_toml_bytes`.
    ``what`` names the kind of file in the not-found message.
    """
    label = str(path)
    raw = read_regular_file(path, label, not_found=f"{label}: {what} not found",
                            error_path=label, max_bytes=TOML_MAX_BYTES, what="TOML file")
    return parse_toml_bytes(raw, label), raw


def read_toml_document(path: Path) -> dict[str, Any]:
    """The parsed TOML document of ``path`` (:func:`read_toml` without the raw bytes)."""
    return read_toml(Path(path))[0]


def _require_table(doc: Mapping[str, Any], key: str, label: str, *, required: bool) -> Mapping | None:
    if key not in doc:
        if required:
            raise ExperimentFormatError(f"{label}: missing required table [{key}]", path=label, key=key)
        return None
    value = doc[key]
    if not isinstance(value, Mapping):
        raise ExperimentFormatError(
            f"{label}: [{key}] must be a table, got {type(value).__name__} {clip(repr(value))}",
            path=label, key=key)
    return value


def parse_toml(doc: Mapping[str, Any], label: str) -> tuple[Design, float, str, str]:
    """Validate the TOML document; return design, rate_hz [Hz], description, data."""
    if "format" not in doc:
        raise ExperimentFormatError(f"{label}: missing required key 'format' (expected \"{FORMAT}\")",
                                    path=label, key="format")
    if doc["format"] != FORMAT:
        raise ExperimentFormatError(f"{label}: format must be \"{FORMAT}\", got {clip(repr(doc['format']))}",
                                    path=label, key="format")
    for key in doc:
        if key not in TOP_LEVEL_KEYS:
            raise ExperimentFormatError(
                f"{label}: unknown top-level key '{clip(key)}'; allowed: {', '.join(TOP_LEVEL_KEYS)}",
                path=label, key=key,
            )
    description = doc.get("description", "")
    if not isinstance(description, str):
        raise ExperimentFormatError(f"{label}: description must be a string, got {clip(repr(description))}",
                                    path=label, key="description")
    if "data" not in doc:
        raise ExperimentFormatError(f"{label}: missing required key 'data' (the CSV file name)",
                                    path=label, key="data")
    data = doc["data"]
    if not isinstance(data, str) or not data.strip() or "\x00" in data:
        raise ExperimentFormatError(f"{label}: data must be a non-empty string (the CSV path), "
                                    f"got {clip(repr(data))}", path=label, key="data")
    sampling = _require_table(doc, "sampling", label, required=True)
    for key in sampling:
        if key != "rate_hz":
            raise ExperimentFormatError(f"{label}: [sampling] unknown key '{clip(key)}'; allowed: rate_hz",
                                        path=label, key=f"sampling.{key}")
    if "rate_hz" not in sampling:
        raise ExperimentFormatError(f"{label}: [sampling] missing required key 'rate_hz'",
                                    path=label, key="sampling.rate_hz")
    rate = check_rate(sampling["rate_hz"], label="[sampling] rate_hz", path=label)
    testbed = Testbed.from_mapping(_require_table(doc, "testbed", label, required=True), source=label)
    environment = Environment.from_mapping(_require_table(doc, "environment", label, required=True),
                                           source=label)
    table = _require_table(doc, "controller", label, required=False)
    controller = None if table is None else controller_from_mapping(table, source=label, rate_hz=rate, code=False)
    table = _require_table(doc, "compensator", label, required=False)
    compensator = None if table is None else Compensator.from_mapping(table, source=label)
    design = Design(testbed=testbed, environment=environment, controller=controller,
                    compensator=compensator)
    return design, rate, description, data


# --- CSV ------------------------------------------------------------------------------


def _not_utf8(label: str, exc: UnicodeDecodeError, offset: int = 0) -> ExperimentFormatError:
    return ExperimentFormatError(f"{label}: not UTF-8 text ({one_line(exc.reason)} at byte "
                                 f"{exc.start + offset})", path=label)


def parse_header(line: str, label: str, required: Iterable[str] = REQUIRED_COLUMNS,
                 role: str = "required columns") -> list[str]:
    """The column names of a header line; empty, duplicate and missing names are errors."""
    names = [cell.strip() for cell in _csv_cells(line, label, 1)] if line.strip() else []
    seen: set[str] = set()
    for j, name in enumerate(names):
        if not name:
            raise ExperimentFormatError(f"{label}: line 1: column {j + 1} has an empty name",
                                        path=label, key="line 1")
        if name in seen:
            raise ExperimentFormatError(f"{label}: line 1: duplicate column '{clip(name)}'",
                                        path=label, key=name)
        seen.add(name)
    required = tuple(required)
    for name in required:
        if name not in seen:
            # a spreadsheet in a comma-decimal locale writes ';' (or a tab) between the columns
            other = next((sep for sep in (";", "\t") if len(names) == 1 and sep in line), None)
            hint = (f"; the header is separated by {'semicolons' if other == ';' else 'tabs'}, the format's CSV "
                    "by commas (with '.' decimals)") if other else ""
            raise ExperimentFormatError(
                f"{label}: column '{name}' missing; {role}: {', '.join(required)}"
                f" (found: {clip(', '.join(names))}){hint}", path=label, key=name,
            )
    return names


def _csv_cells(line: str, label: str, lineno: int) -> list[str]:
    """The cells of one CSV line; the csv module's own complaints (a NUL, a huge field) as one line."""
    try:
        return next(csv.reader([line]))
    except csv.Error as exc:
        raise ExperimentFormatError(f"{label}: line {lineno}: not a CSV line ({one_line(exc)})", path=label,
                                    key=f"line {lineno}") from None


def _scan_rows(lines: Iterable[str], names: list[str], label: str, use: list[int] | None = None,
               n_rows: int | None = None) -> np.ndarray:
    """Slow path: parse row by row (the cells of columns ``use``) and name the first bad line.

    ``lines`` may be a list or an iterator (``n_rows``: at most that many, for the array).
    """
    width = len(names)
    use = list(range(width)) if use is None else use
    out = np.empty((len(lines) if n_rows is None else n_rows, len(use)))  # type: ignore[arg-type]
    i = -1
    for i, line in enumerate(lines):
        lineno = i + 2
        if not line.strip():
            raise ExperimentFormatError(f"{label}: line {lineno} is empty; blank lines are only "
                                        "allowed at the end", path=label, key=f"line {lineno}")
        row = _csv_cells(line, label, lineno)
        if len(row) != width:
            raise ExperimentFormatError(
                f"{label}: line {lineno} has {len(row)} fields but the header (line 1) has {width} "
                f"columns", path=label, key=f"line {lineno}",
            )
        for k, j in enumerate(use):
            cell = row[j]
            if _NUMBER.fullmatch(cell) is None:
                raise ExperimentFormatError(
                    f"{label}: line {lineno}, column '{clip(names[j])}': {clip(repr(cell))} is not a number",
                    path=label, key=names[j],
                )
            out[i, k] = float(cell)
    return out[:i + 1]


def _line_breaks(raw: bytes | mmap.mmap, start: int, stop: int) -> int:
    """Line breaks in ``raw[start:stop]`` (LF, or CR in a CR-only file), counted in bounded chunks."""
    def count(byte: bytes) -> int:
        return sum(raw[i:min(i + (1 << 26), stop)].count(byte) for i in range(start, stop, 1 << 26))

    lf = count(b"\n")
    return lf if lf else count(b"\r")


def _iter_lines(raw: bytes | mmap.mmap, start: int, stop: int, label: str) -> Iterable[str]:
    """The lines of ``raw[start:stop]`` (LF, CRLF or CR ends), each decoded alone: no copy of the whole file."""
    pos, lineno = start, 2
    lf = raw.find(b"\n", pos, stop)
    while pos < stop:
        if lf != -1 and lf < pos:
            lf = raw.find(b"\n", pos, stop)
        end = stop if lf == -1 else lf
        cr = raw.find(b"\r", pos, end)
        nxt = end + 1
        if cr != -1:
            end, nxt = cr, cr + 2 if cr + 1 == lf else cr + 1
        if end - pos > CSV_MAX_LINE_BYTES:
            raise ExperimentFormatError(f"{label}: line {lineno} is longer than {CSV_MAX_LINE_BYTES} bytes; not a "
                                        "row of this format", path=label, key=f"line {lineno}")
        try:
            yield raw[pos:end].decode("utf-8")
        except UnicodeDecodeError as exc:
            raise _not_utf8(label, exc, pos) from None
        pos, lineno = nxt, lineno + 1


def _header_end(raw: bytes, start: int, limit: int | None = None) -> tuple[int, int]:
    """(end of the header line, start of the first row) in ``raw``; LF, CRLF or CR.

    With ``limit``, no further than ``limit`` bytes are looked at (a file without a line break in them
    gives an end beyond ``start + limit``; nothing after it is touched).
    """
    end = len(raw) if limit is None else min(len(raw), start + limit + 2)
    lf = raw.find(b"\n", start, end)
    cr = raw.find(b"\r", start, end if lf == -1 else lf + 1)  # look no further than the LF
    if cr != -1 and (lf == -1 or cr < lf):
        return cr, cr + 2 if raw[cr + 1:cr + 2] == b"\n" else cr + 1
    if lf != -1:
        return lf, lf + 1
    return end, end


def _columnar(body: memoryview, width: int, use: list[int] | None = None) -> list[np.ndarray] | None:
    """pyarrow's reader on the rows (columns ``use`` only); None when it finds anything irregular."""
    import pyarrow as pa  # imported on first read: keeps `forecast-design --help` light
    import pyarrow.csv as pa_csv

    names = [f"c{j}" for j in range(width)]
    try:
        table = pa_csv.read_csv(
            pa.py_buffer(body),
            read_options=pa_csv.ReadOptions(column_names=names, use_threads=True,
                                            block_size=1 << 22),
            parse_options=pa_csv.ParseOptions(ignore_empty_lines=False, newlines_in_values=False),
            convert_options=pa_csv.ConvertOptions(
                column_types={n: pa.float64() for n in names}, null_values=[],
                strings_can_be_null=False, quoted_strings_can_be_null=False,
                include_columns=None if use is None else [names[j] for j in use]),
        )
    except (pa.ArrowInvalid, pa.ArrowTypeError, pa.ArrowNotImplementedError):
        return None
    out = []
    for j in range(table.num_columns):
        # The chunks' data buffers as numpy arrays: no nulls (null_values=[]), and no
        # ChunkedArray.to_numpy, which imports pandas (0.5 s) to do the same.
        parts = [np.frombuffer(ch.buffers()[1], dtype=np.float64, count=len(ch), offset=ch.offset * 8)
                 for ch in table.column(j).chunks if ch.null_count == 0]
        if len(parts) != table.column(j).num_chunks:
            return None
        out.append(parts[0] if len(parts) == 1 else np.concatenate(parts) if parts else np.empty(0))
    del table
    # the parser's blocks and the chunks copied out above go back to the system: pyarrow's pool keeps
    # freed pages otherwise, about 90 B per sample of a six-column log for the rest of the process
    pa.default_memory_pool().release_unused()
    return out


def read_csv_table(raw: bytes | mmap.mmap, label: str, *, required: Iterable[str] = REQUIRED_COLUMNS,
                   role: str = "required columns",
                   usecols: Iterable[str] | None = None,
                   max_rows: int | None = None,
                   reader: str = "this command") -> tuple[list[str], dict[str, np.ndarray]]:
    """Parse a CSV file's bytes into float64 columns.

    Parameters
    ----------
    raw : bytes or mmap.mmap
        The whole file.
    label : str
        How errors name the file.
    required : iterable of str
        Column names the header must contain.
    role : str
        What errors call the required names.
    usecols : iterable of str, optional
        Convert only these columns (they must be in the header); the cells of the
        others are not checked. Default: every column.
    max_rows : int, optional
        Most data rows accepted (default :data:`DEFAULT_MAX_SAMPLES`): the file's size and its
        line breaks are checked against it before anything is parsed or allocated.
    reader : str
        Who reads the file, for the message of ``max_rows`` (e.g. ``"diagnose"``).

    Returns
    -------
    names : list[str]
        The header's column names, in file order.
    columns : dict[str, numpy.ndarray]
        One float64 array of shape (n,) per converted column, n >= 1.

    Raises
    ------
    ExperimentFormatError
        One line naming the file and the line (the header is line 1) and column.
    """
    if max_rows is not None and (isinstance(max_rows, bool) or not isinstance(max_rows, (int, np.integer))
                                 or max_rows < 1):
        raise ParameterError(f"max_samples must be an integer >= 1, got {clip(repr(max_rows))}", name="max_samples",
                             value=max_rows)
    limit = DEFAULT_MAX_SAMPLES if max_rows is None else int(max_rows)
    start = len(_BOM) if raw[:len(_BOM)] == _BOM else 0
    stop = len(raw)
    while stop > start and raw[stop - 1] in b" \t\r\n":
        stop -= 1
    if stop == start:
        raise ExperimentFormatError(
            f"{label}: empty file; expected a header line with columns {', '.join(required)}",
            path=label, key="line 1",
        )
    head_end, body_start = _header_end(raw, start, CSV_MAX_LINE_BYTES)
    if head_end - start > CSV_MAX_LINE_BYTES:
        raise ExperimentFormatError(f"{label}: line 1 (the header) is longer than {CSV_MAX_LINE_BYTES} bytes; "
                                    "not a CSV file of this format", path=label, key="line 1")
    try:
        header = raw[start:head_end].decode("utf-8")
    except UnicodeDecodeError as exc:
        raise _not_utf8(label, exc, start) from None
    if "\x00" in header:
        raise ExperimentFormatError(f"{label}: line 1 holds a NUL byte; not a CSV text file", path=label,
                                    key="line 1")
    names = parse_header(header, label, required, role)
    if body_start >= stop:
        raise ExperimentFormatError(f"{label}: no data rows (header only)", path=label, key="line 2")
    # bounded before anything is parsed: the size (a row's cells at most CSV_MAX_CELL_BYTES each), then the rows
    why = f"{reader} reads at most {limit} rows (docs/reliability.md, limits of a log's size); cut the log"
    if stop - body_start > limit * len(names) * CSV_MAX_CELL_BYTES:
        raise ExperimentFormatError(f"{label}: {stop - body_start} bytes of rows, more than {limit} rows of "
                                    f"{len(names)} cells can hold; {why}", path=label)
    n_rows = _line_breaks(raw, body_start, stop) + 1
    if n_rows > limit:
        raise ExperimentFormatError(f"{label}: {n_rows} rows; {why}", path=label)
    use = None if usecols is None else sorted({names.index(n) for n in usecols if n in names})
    view = memoryview(raw)
    # The trimmed rows end without a line break; pyarrow reads the last row all the same.
    columns = _columnar(view[body_start:stop], len(names), use)
    del view
    if columns is None:
        table = _scan_rows(_iter_lines(raw, body_start, stop, label), names, label, use, n_rows=n_rows)
        columns = [table[:, k] for k in range(table.shape[1])]
    kept = names if use is None else [names[j] for j in use]
    return names, dict(zip(kept, columns))


# --- experiments ----------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class ExperimentFiles:
    """What the files of one experiment hold, checked for form but not for sample rules.

    Parameters
    ----------
    design : Design
        Testbed, environment, controller and compensator of the TOML.
    rate_hz : float
        ``[sampling] rate_hz`` [Hz].
    description : str
        Free text.
    data : str
        The TOML's ``data`` key.
    toml_path : pathlib.Path
        The TOML file.
    csv_label : str
        The CSV file as errors name it.
    names : list[str]
        CSV column names in file order.
    columns : dict[str, numpy.ndarray]
        One float64 array per column (units of the format).
    """

    design: Design
    rate_hz: float
    description: str
    data: str
    toml_path: Path
    csv_label: str
    names: list[str]
    columns: dict[str, np.ndarray]


def _verify_checksum(toml_raw: bytes, csv_raw: bytes | mmap.mmap, toml_label: str, csv_label: str) -> None:
    match = _CHECKSUM.search(toml_raw)
    if match is None:
        if _CHECKSUM_KEY.search(toml_raw):      # meant as the checksum, but garbled: never silently unchecked
            raise ExperimentFormatError(
                f"{toml_label}: its '# data-crc32' line is not '# data-crc32 = XXXXXXXX, data-bytes = N' (8 lowercase "
                f"hex digits); it cannot vouch for {csv_label}: restore it, or delete it to accept the CSV as it is",
                path=toml_label, key="data-crc32")
        return  # written by another tool: nothing to verify
    crc, size = match.group(1).decode(), int(match.group(2))
    if len(csv_raw) != size or f"{zlib.crc32(csv_raw):08x}" != crc:
        raise ExperimentFormatError(
            f"{csv_label}: does not match {toml_label} (its '# data-crc32' line records {size} bytes, "
            f"crc32 {crc}; the file has {len(csv_raw)} bytes, crc32 {zlib.crc32(csv_raw):08x}): a save "
            f"was interrupted or the CSV was edited; delete that comment line to accept the CSV as it is",
            path=csv_label, key="data")


def read_experiment_files(path: str | os.PathLike[str], *, max_samples: int | None = None,
                          reader: str = "this command") -> ExperimentFiles:
    """Read and parse an experiment's TOML and CSV (see the module notes for what is accepted).

    Parameters
    ----------
    path : str or os.PathLike
        The TOML file; its ``data`` key names the CSV, relative to the TOML's folder.
    max_samples : int, optional
        Most samples (CSV rows) accepted, checked before the CSV is parsed (default
        :data:`DEFAULT_MAX_SAMPLES`).
    reader : str
        Who reads the log, for the message of ``max_samples``.

    Returns
    -------
    ExperimentFiles
        The parsed content.

    Raises
    ------
    ExperimentFormatError
        One line naming the file and the key, column or CSV line.
    """
    toml_path = Path(path)
    toml_label = str(toml_path)
    doc, toml_raw = read_toml(toml_path)
    design, rate, description, data = parse_toml(doc, toml_label)
    csv_path = toml_path.parent / data
    csv_label = str(csv_path)
    key_is = f"the 'data' key of {toml_label} is {clip(repr(data))}"
    raw = read_regular_file(
        csv_path, csv_label, not_found=f"{csv_label}: CSV file not found ({key_is})",
        unreadable=f"{csv_label}: cannot read CSV ({{reason}}; {key_is})", error_path=toml_label,
        error_key="data", mapped=True)
    _verify_checksum(toml_raw, raw, toml_label, csv_label)
    names, columns = read_csv_table(raw, csv_label, max_rows=max_samples, reader=reader)
    del raw
    return ExperimentFiles(design=design, rate_hz=rate, description=description, data=data,
                           toml_path=toml_path, csv_label=csv_label, names=names, columns=columns)


def csv_chunks(columns: Mapping[str, np.ndarray]) -> Iterable[str]:
    """The CSV text of ``columns`` (header, then ``%.17g`` rows), in chunks of rows."""
    yield ",".join(columns) + "\n"
    row_format = ",".join([_CSV_FORMAT] * len(columns)) + "\n"
    arrays = list(columns.values())
    n = arrays[0].shape[0]
    for start in range(0, n, _WRITE_CHUNK):
        block = zip(*(a[start:start + _WRITE_CHUNK].tolist() for a in arrays))
        yield "".join([row_format % row for row in block])


def data_name(toml_path: Path, data: str | os.PathLike[str] | None) -> str:
    """The ``data`` key for a CSV written beside ``toml_path`` (default: same stem, ``.csv``)."""
    if data is None:
        data_str = toml_path.with_suffix(".csv").name
    else:
        data_path = Path(data)
        if data_path.is_absolute():
            data_path = Path(os.path.relpath(data_path, os.path.realpath(toml_path.parent)))
        data_str = data_path.as_posix()
    # realpath, not Path.resolve: a symlink loop is the writer's one-line error, not a RuntimeError here
    if Path(os.path.realpath(toml_path.parent)) / data_str == Path(os.path.realpath(toml_path)):
        raise ParameterError(f"data {data_str!r} would overwrite the TOML file {toml_path}",
                             name="data", value=data_str)
    return data_str


def write_experiment_files(toml_path: str | os.PathLike[str], mapping: Mapping[str, Any],
                           columns: Mapping[str, np.ndarray],
                           sidecars: Mapping[str | os.PathLike[str], Content] | None = None) -> Path:
    """Write the TOML ``mapping`` and the CSV ``columns`` as one set (CSV first, TOML last).

    Parameters
    ----------
    toml_path : str or os.PathLike
        The TOML file; the CSV goes to ``mapping['data']`` relative to its folder.
    mapping : Mapping
        The TOML document (``Experiment.to_mapping``).
    columns : Mapping[str, numpy.ndarray]
        The CSV columns in order, each of shape (n,).
    sidecars : Mapping[path, content], optional
        Further files of the same set (e.g. a simulation's truth), written before the
        experiment's CSV and TOML (see :func:`forecast_design.fileio.atomic_write_set`).

    Returns
    -------
    pathlib.Path
        The TOML path.

    Raises
    ------
    OutputError
        If any file cannot be written; then none is changed.
    """
    toml_path = Path(toml_path)
    csv_path = toml_path.parent / mapping["data"]
    state = {"crc": 0, "size": 0}

    def counted() -> Iterable[bytes]:
        for chunk in csv_chunks(columns):
            data = chunk.encode("utf-8")
            state["crc"] = zlib.crc32(data, state["crc"])
            state["size"] += len(data)
            yield data

    def toml_text() -> Iterable[str]:
        yield tomli_w.dumps(dict(mapping))
        yield f"# data-crc32 = {state['crc']:08x}, data-bytes = {state['size']}\n"

    files: dict[Any, Any] = dict(sidecars or {})
    files[csv_path] = counted()
    files[toml_path] = _Lazy(toml_text)
    atomic_write_set(files)
    return toml_path


class _Lazy:
    """An iterable whose chunks are produced only when iterated (after earlier set members)."""

    def __init__(self, make):
        self._make = make

    def __iter__(self):
        return iter(self._make())
