"""Reading files from outside, bounded, and writing files whole: the one place depthguard opens a user's file.

Every reader here:

- reads only regular files (a FIFO, a device such as ``/dev/zero`` or ``/dev/stdin``, a socket or a folder is refused
  before it is opened, so nothing blocks or reads forever);
- reads at most a size cap (``config.MAX_*_BYTES``), and refuses a larger file without reading it;
- raises the caller's :class:`~depthguard.errors.DepthguardError` subclass, naming the file.

Text formats are parsed without running code and within bounds:

- YAML (:func:`load_yaml`): PyYAML's safe constructors; anchors and aliases are refused (an alias can expand a small
  file into gigabytes), so are duplicate keys (a typo's second value must not silently win) and nesting deeper than
  ``config.MAX_NESTING``.
- JSON (:func:`load_json`): numbers are read as floats (a 400-digit integer becomes inf, which the caller's range
  check refuses, instead of an integer no float can hold); nesting too deep for the parser is an error.

Every file depthguard writes is written whole or not at all (:func:`atomic_write`, :func:`write_whole`,
:func:`atomic_folder`): into a temporary file beside it, flushed to disk, then renamed over it in one step. A process
stopped while writing leaves the older file or none, never a shorter one that a reader would take for valid (a rig
with one camera fewer). The temporary name, ``.<name>.<pid>.<n>.partial``, is hidden and ends in ``.partial``: no
reader looks for it, and no glob such as ``*.png`` or ``*.yaml`` matches it. A write that fails (a full disk, a
read-only or missing folder, a closed pipe) raises :class:`~depthguard.errors.WriteError` naming the file and why
(:func:`write_error`); standard output's writes do the same within :func:`named_stdout`, which every command line
runs in.
"""

from __future__ import annotations

import contextlib
import csv
import io
import itertools
import json
import os
import shutil
import stat
import sys
from pathlib import Path

import yaml

from depthguard import config
from depthguard.errors import DepthguardError, InputError, WriteError
from depthguard.validation import short_repr


def read_bytes(path, *, what: str, max_bytes: int, error: type[DepthguardError] = InputError, **context) -> bytes:
    """The whole content of the regular file ``path``, at most ``max_bytes`` bytes.

    ``what`` names the file's role in messages ("rig file", "points file"); ``context`` (``camera=``, ``field=``) is
    passed to ``error``. Raises ``error`` for a missing, unreadable, non-regular or too large file.
    """
    path = Path(path)
    try:
        info = os.stat(path)  # follows symlinks: a link to a regular file is fine
    except OSError as exc:
        raise error(f"cannot read {what} ({exc.strerror or exc})", source=str(path), **context) from None
    _check_regular(info, path, what, max_bytes, error, context)
    try:
        # O_NONBLOCK: should the path have been swapped for a FIFO since the check, opening it does not wait for a
        # writer; fstat below then refuses it.
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
    except OSError as exc:
        raise error(f"cannot read {what} ({exc.strerror or exc})", source=str(path), **context) from None
    try:
        _check_regular(os.fstat(fd), path, what, max_bytes, error, context)
        chunks = []
        remaining = max_bytes + 1
        while remaining > 0:
            chunk = os.read(fd, min(remaining, 1 << 20))
            if not chunk:
                break
            chunks.append(chunk)
            remaining -= len(chunk)
    except OSError as exc:
        raise error(f"cannot read {what} ({exc.strerror or exc})", source=str(path), **context) from None
    finally:
        os.close(fd)
    data = b"".join(chunks)
    if len(data) > max_bytes:  # the file grew while it was read
        raise error(f"{what} is larger than {max_bytes} bytes", source=str(path), **context)
    return data


def check_regular_file(path, *, what: str, max_bytes: int, error: type[DepthguardError] = InputError,
                       **context) -> Path:
    """``path`` as a :class:`Path` after checking that it is a regular file of at most ``max_bytes`` bytes, for a
    library that opens the file itself (Pillow, trimesh). Raises ``error`` otherwise."""
    path = Path(path)
    try:
        info = os.stat(path)
    except OSError as exc:
        raise error(f"cannot read {what} ({exc.strerror or exc})", source=str(path), **context) from None
    _check_regular(info, path, what, max_bytes, error, context)
    return path


def read_text(path, *, what: str, max_bytes: int, error: type[DepthguardError] = InputError, **context) -> str:
    """:func:`read_bytes` decoded as UTF-8 (a leading byte-order mark, as spreadsheets write, is dropped)."""
    data = read_bytes(path, what=what, max_bytes=max_bytes, error=error, **context)
    try:
        return data.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise error(f"{what} is not UTF-8 text", source=str(path), **context) from None


def _check_regular(info: os.stat_result, path: Path, what: str, max_bytes: int, error, context) -> None:
    if stat.S_ISDIR(info.st_mode):
        raise error(f"{what} is a folder, not a file", source=str(path), **context)
    if not stat.S_ISREG(info.st_mode):
        raise error(f"{what} is not a regular file (a device, pipe or socket is never read)", source=str(path),
                    **context)
    if info.st_size > max_bytes:
        raise error(f"{what} is {info.st_size} bytes, more than the {max_bytes} allowed", source=str(path),
                    **context)


# ------------------------------------------------------------------------------------------------------------- YAML


class _BoundedSafeLoader(yaml.SafeLoader):
    """PyYAML's safe loader without aliases, duplicate keys or deep nesting."""

    def __init__(self, stream):
        super().__init__(stream)
        self._depth = 0

    def compose_node(self, parent, index):
        if self.check_event(yaml.AliasEvent):
            event = self.peek_event()
            raise yaml.composer.ComposerError(None, None, "YAML aliases (*name) are not accepted: write the value out",
                                              event.start_mark)
        event = self.peek_event()
        if getattr(event, "anchor", None) is not None:
            raise yaml.composer.ComposerError(None, None, "YAML anchors (&name) are not accepted: write the value out",
                                              event.start_mark)
        self._depth += 1
        try:
            if self._depth > config.MAX_NESTING:
                raise yaml.composer.ComposerError(None, None, f"nested deeper than {config.MAX_NESTING} levels",
                                                  event.start_mark)
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1

    def construct_mapping(self, node, deep=False):
        if isinstance(node, yaml.MappingNode):
            seen = set()
            for key_node, _ in node.value:
                key = self.construct_object(key_node, deep=True)
                try:
                    duplicate = key in seen
                    seen.add(key)
                except TypeError:  # an unhashable key: the base class reports it
                    continue
                if duplicate:
                    raise yaml.constructor.ConstructorError(None, None, f"duplicate key {key!r}",
                                                            key_node.start_mark)
        return super().construct_mapping(node, deep=deep)


def load_yaml(text: str, *, source, error: type[DepthguardError] = InputError, **context):
    """Parse YAML ``text`` with safe constructors only; ``error`` naming ``source`` if it is malformed, uses anchors
    or aliases, repeats a key or nests deeper than ``config.MAX_NESTING``."""
    try:
        return yaml.load(text, Loader=_BoundedSafeLoader)  # noqa: S506 - a SafeLoader subclass
    except yaml.constructor.ConstructorError as exc:
        if "could not determine a constructor for the tag" in str(exc.problem):  # !!python/..., a custom !tag
            raise error(f"a YAML tag that is not allowed ({_one_line(exc)})", source=str(source),
                        **context) from None
        raise error(f"malformed YAML ({_one_line(exc)})", source=str(source), **context) from None
    except yaml.YAMLError as exc:
        raise error(f"malformed YAML ({_one_line(exc)})", source=str(source), **context) from None
    except (ValueError, OverflowError) as exc:  # a scalar no Python value holds: an integer of 4301+ digits, a
        # timestamp such as 2001-13-45
        raise error(f"malformed YAML: a value that cannot be read ({_one_line(exc)[:200]})", source=str(source),
                    **context) from None
    except RecursionError:  # nesting inside a single scalar flow cannot get here, but stay safe
        raise error(f"YAML nested deeper than {config.MAX_NESTING} levels", source=str(source), **context) from None


def read_yaml(path, *, what: str, max_bytes: int = config.MAX_TEXT_FILE_BYTES,
              error: type[DepthguardError] = InputError, **context):
    """:func:`read_text` then :func:`load_yaml`."""
    return load_yaml(read_text(path, what=what, max_bytes=max_bytes, error=error, **context), source=path,
                     error=error, **context)


# ------------------------------------------------------------------------------------------------------------- JSON


def _json_number(text: str) -> float:
    return float(text)  # a huge literal becomes inf (or 0.0), never an int that no float holds


def load_json(text: str, *, source, error: type[DepthguardError] = InputError, **context):
    """Parse JSON ``text`` with every number read as a float; ``error`` naming ``source`` if it is malformed or nested
    too deep for the parser (Python's recursion limit; the C parser reports it as RecursionError, never crashes).
    NaN and Infinity literals are read as floats: callers check ranges."""
    try:
        return json.loads(text, parse_int=_json_number, parse_float=_json_number)
    except json.JSONDecodeError as exc:
        raise error(f"malformed JSON ({exc.msg} at line {exc.lineno})", source=str(source), **context) from None
    except RecursionError:
        raise error("JSON nested too deeply", source=str(source), **context) from None


def _one_line(exc: Exception) -> str:
    return " ".join(str(exc).split())


def csv_table(text: str, *, source, error: type[DepthguardError] = InputError,
              check_header=None) -> tuple[list[str], list]:
    """(header, [(line number, cells), ...]) of a CSV text: the header's names stripped, and every row that is not
    blank. Every row must hold exactly as many fields as the header (docs/bad-input.md, "tables with a wrong
    shape"): a row with more is not cut short silently, one with fewer is not padded. Otherwise, and for malformed
    CSV (a quote left open, a field longer than ``csv.field_size_limit()``), ``error`` naming ``source`` and the
    line. ``check_header(names)``, when given, judges the header (stripped names) before any row is read."""
    reader = csv.reader(io.StringIO(text, newline=""))
    rows = []
    try:
        header = next(reader, None)
        if header is None:
            raise error("empty file; expected a header line", source=str(source))
        if check_header is not None:
            check_header([cell.strip() for cell in header])
        for row in reader:
            if not any(cell.strip() for cell in row):
                continue
            if len(row) != len(header):  # a short row names the first column it lacks
                raise error(f"line {reader.line_num}: {len(row)} fields, but the header has {len(header)} "
                            f"({short_repr(','.join(header), 60)})", source=str(source),
                            field=header[len(row)].strip() if len(row) < len(header) else None)
            rows.append((reader.line_num, row))
    except csv.Error as exc:
        raise error(f"line {reader.line_num}: malformed CSV ({_one_line(exc)})", source=str(source)) from None
    return [cell.strip() for cell in header], rows


# ---------------------------------------------------------------------------------------------------------- writing

_partial_numbers = itertools.count()  # tells apart the temporary files of one process's threads


def _partial_path(path: Path) -> Path:
    return path.with_name(f".{path.name}.{os.getpid()}.{next(_partial_numbers)}.partial")


@contextlib.contextmanager
def atomic_write(path, mode: str = "w", *, newline: str | None = None):
    """Write the file ``path`` whole: ``with atomic_write(path) as f:`` gives a new temporary file beside ``path``
    (text in UTF-8 for ``mode="w"``, bytes for ``"wb"``; ``newline`` as :func:`open`'s). When the block ends without
    an error, the file is flushed to disk and renamed to ``path``, replacing an older file in one step. When it
    raises, ``path`` is left as it was (the older file, or none) and the temporary file is removed.

    An :class:`OSError` opening or renaming the file names ``path``, not the temporary name.
    """
    if mode not in ("w", "wb"):
        raise ValueError(f"atomic_write writes a new file: mode 'w' or 'wb', got {mode!r}")
    path = Path(path)
    partial = _partial_path(path)
    with _writing(path, partial):
        # "x": the temporary file is new, never an existing file or a link planted under its name.
        file = open(partial, mode.replace("w", "x"), encoding=None if mode == "wb" else "utf-8", newline=newline)
    try:
        with _writing(path, partial):
            with file:
                yield file
                file.flush()
                os.fsync(file.fileno())
            os.replace(partial, path)
    finally:
        with contextlib.suppress(OSError):
            partial.unlink(missing_ok=True)  # after an error; after the rename there is nothing left
    _sync_folder(path.parent)


def write_whole(path, data: str | bytes) -> None:
    """Write ``data`` (text, as UTF-8, or bytes) to the file ``path`` whole (:func:`atomic_write`)."""
    with atomic_write(path, "wb" if isinstance(data, bytes) else "w") as file:
        file.write(data)


@contextlib.contextmanager
def atomic_folder(path):
    """Write the new folder ``path`` whole: ``with atomic_folder(path) as folder:`` gives a path that does not exist
    yet, for the block to create and fill (a library that writes a folder of its own, such as a ROS 2 bag). It lies in
    a hidden temporary folder beside ``path`` and has ``path``'s name, so names written from it inside the folder are
    the final ones. When the block ends without an error, every file in it is flushed to disk and the folder is
    renamed to ``path``, which must not exist (or be an empty folder). When it raises, no ``path`` appears and the
    temporary folder is removed. Missing folders above ``path`` are created."""
    path = Path(path)
    holder = _partial_path(path)
    with _writing(path, holder):
        holder.mkdir(parents=True)
    try:
        folder = holder / path.name
        with _writing(path, holder):
            yield folder
            for file in sorted(folder.rglob("*")):
                if file.is_file() and not file.is_symlink():
                    _sync_file(file)
            os.replace(folder, path)
    finally:
        shutil.rmtree(holder, ignore_errors=True)
    _sync_folder(path.parent)


def write_error(name, exc: OSError) -> WriteError:
    """The one error for a write that failed (docs/bad-input.md, "files the writer cannot finish"): ``name`` (a file,
    or "standard output") could not be written, and why (the OS's words: "No space left on device", "Read-only file
    system", "Broken pipe"), in one line."""
    reason = exc.strerror or _one_line(exc) or type(exc).__name__
    error = WriteError(f"could not be written: {reason}", source=str(name))
    error.errno, error.strerror, error.filename = exc.errno, exc.strerror, str(name)  # as an OSError says it
    return error


@contextlib.contextmanager
def _writing(path: Path, temporary: Path):
    """An :class:`OSError` of writing ``path`` (through its ``temporary`` name) within becomes :func:`write_error`
    naming ``path``, what the caller asked for. An OSError about another file (one the block reads) passes as it
    is: it carries that file's name."""
    try:
        yield
    except WriteError:
        raise
    except OSError as exc:
        if exc.filename is None or str(exc.filename) == str(path) or str(exc.filename).startswith(str(temporary)):
            raise write_error(path, exc) from None
        raise


class _NamedOutput:
    """A text stream whose write and flush errors are :func:`write_error` naming ``name`` ("standard output")."""

    def __init__(self, stream, name: str):
        self._stream = stream
        self._name = name

    def write(self, text):
        try:
            return self._stream.write(text)
        except OSError as exc:
            raise self._failed(exc) from None

    def flush(self):
        try:
            self._stream.flush()
        except OSError as exc:
            raise self._failed(exc) from None

    def _failed(self, exc: OSError) -> WriteError:
        # What is still buffered would fail again when Python flushes at exit, with a traceback on standard error:
        # the stream's file descriptor goes to os.devnull instead (as Python's documentation advises for SIGPIPE).
        with contextlib.suppress(OSError, ValueError, AttributeError):
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, self._stream.fileno())
            os.close(devnull)
        return write_error(self._name, exc)

    def __getattr__(self, attribute):
        return getattr(self._stream, attribute)


@contextlib.contextmanager
def named_stdout():
    """Within, ``sys.stdout``'s write errors (a full disk, ``/dev/full``, a closed pipe) are :func:`write_error`
    naming standard output; at the end it is flushed, so that such an error comes before the exit status is set."""
    original = sys.stdout
    sys.stdout = _NamedOutput(original, "standard output") if original is not None else original
    try:
        yield
        if sys.stdout is not None:
            sys.stdout.flush()
    finally:
        sys.stdout = original


def _sync_file(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY | getattr(os, "O_CLOEXEC", 0))
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _sync_folder(folder: Path) -> None:
    """Make a rename in ``folder`` survive a power cut (POSIX; where a folder cannot be opened, nothing to do)."""
    try:
        fd = os.open(folder, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0) | getattr(os, "O_CLOEXEC", 0))
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass  # a file system that cannot sync folders
    finally:
        os.close(fd)
