"""Helpers for tests of hostile input files: watch for started processes, fail instead of hanging, hand-made files."""

from __future__ import annotations

import contextlib
import signal
import struct
import sys
import threading
import zlib

#: Audit events that mean a process was (or was about to be) started.
PROCESS_EVENTS = ("subprocess.Popen", "os.system", "os.posix_spawn", "os.spawn", "os.exec", "os.fork",
                  "os.forkpty", "pty.spawn")

_recorders: list[list] = []
_installed = False


def _hook(event, args):
    if _recorders and event.startswith(PROCESS_EVENTS):
        for recorder in _recorders:
            recorder.append((event, args))


@contextlib.contextmanager
def no_process_started():
    """Fail the test if anything inside the block starts (or tries to start) a process.

    An audit hook cannot be removed once added, so one hook is installed for the session and records only while a
    block is open."""
    global _installed
    if not _installed:
        sys.addaudithook(_hook)
        _installed = True
    events: list = []
    _recorders.append(events)
    try:
        yield events
    finally:
        _recorders.remove(events)
    assert not events, f"a process was started: {events}"


@contextlib.contextmanager
def deadline(seconds: int = 5):
    """Fail (instead of hanging) if the block takes longer than ``seconds`` (main thread, POSIX)."""
    if threading.current_thread() is not threading.main_thread():  # pragma: no cover - pytest runs tests there
        yield
        return

    def expired(signum, frame):
        raise TimeoutError(f"took longer than {seconds} s: the reader blocked")

    previous = signal.signal(signal.SIGALRM, expired)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


def npy_bytes(descr: str, shape, fortran_order: bool = False, payload: bytes = b"", version=(1, 0),
              header: str | None = None) -> bytes:
    """A ``.npy`` file written by hand from the format's description (NEP 1): magic, version, header length
    (little-endian uint16 for 1.0, uint32 for 2.0), the header dict as a Python literal padded with spaces and a
    newline to a multiple of 64 bytes, then ``payload``. ``header`` replaces the dict text as given."""
    if header is None:
        header = f"{{'descr': {descr!r}, 'fortran_order': {fortran_order}, 'shape': {tuple(shape)!r}, }}"
    size_format = "<H" if version[0] == 1 else "<I"
    prefix = 6 + 2 + struct.calcsize(size_format)
    text = header.encode("latin1")
    pad = -(prefix + len(text) + 1) % 64
    text = text + b" " * pad + b"\n"
    return b"\x93NUMPY" + bytes(version) + struct.pack(size_format, len(text)) + text + payload


def png_bytes(width: int, height: int, bit_depth: int = 16, colour_type: int = 0, rows: bytes | None = None) -> bytes:
    """A PNG written by hand from the specification: signature, IHDR, one IDAT, IEND (CRCs computed)."""

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    if rows is None:
        rows = b"\x00" * 64
    header = struct.pack(">IIBBBBB", width, height, bit_depth, colour_type, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(rows))
            + chunk(b"IEND", b""))


#: A minimal Encapsulated PostScript file that Pillow's EPS plugin accepts (its loader runs Ghostscript).
EPS = (b"%!PS-Adobe-3.0 EPSF-3.0\n%%BoundingBox: 0 0 4 3\n%%EndComments\n"
       b"newpath 0 0 moveto 4 3 lineto stroke showpage\n%%EOF\n")
