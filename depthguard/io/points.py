"""Reading control points from files: CSV with an ``x,y,z`` header, or JSON holding a list of [x, y, z].

A points file is input from outside (docs/bad-input.md). It is read through :mod:`depthguard.io.files`: a regular file of at most
``config.MAX_POINTS_FILE_BYTES`` bytes, UTF-8 text (a leading byte-order mark is dropped). Every coordinate must be a
finite number of metres with ``|x|, |y|, |z| <= config.COORDINATE_LIMIT``. Any problem is an
:class:`~depthguard.errors.InputError` naming the file and the line (CSV) or entry (JSON).

- CSV: the first line is a header naming the columns ``x``, ``y`` and ``z`` (case-insensitive, once each; other
  columns are ignored). Every row holds as many fields as the header (:func:`depthguard.io.files.csv_table`). Each
  further line holds plain decimal numbers in those columns (``1``, ``-0.25``, ``1e-3``;
  not ``nan``, ``inf``, ``1_000`` or non-ASCII digits). Blank lines are skipped. A file holding only the header has
  no points; an empty file is an error (the header is missing).
- JSON: a list of ``[x, y, z]`` lists of numbers; ``[]`` has no points. Numbers are read as floats (a 400-digit
  integer is out of range, not an exact integer), ``NaN`` and ``Infinity`` are refused, so is nesting deeper than the
  parser allows.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from depthguard import config
from depthguard.io.files import csv_table, load_json, read_text
from depthguard.errors import InputError
from depthguard.validation import short_repr

#: A plain decimal number: what the CSV reader accepts in a coordinate column.
_NUMBER = re.compile(r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")


def load_points(path) -> np.ndarray:
    """(n, 3) float64 metres, world frame, from a ``.json`` (list of [x, y, z]) or any other-named CSV file
    (header ``x,y,z``); see the module docstring for the formats and the checks.

    Raises :class:`InputError` naming the file and the line or entry at fault.
    """
    path = Path(path)
    text = read_text(path, what="points file", max_bytes=config.MAX_POINTS_FILE_BYTES, error=InputError)
    if path.suffix.lower() == ".json":
        return _from_json(text, path)
    return _from_csv(text, path)


def _from_json(text: str, path: Path) -> np.ndarray:
    data = load_json(text, source=path, error=InputError)
    if not isinstance(data, list):
        raise InputError(f"expected a JSON list of [x, y, z], got {type(data).__name__}", source=str(path))
    points = np.empty((len(data), 3))
    for i, entry in enumerate(data):
        if not (isinstance(entry, list) and len(entry) == 3 and all(_is_number(x) for x in entry)):
            raise InputError(f"entry #{i} must be [x, y, z] of numbers, got {short_repr(entry)}", source=str(path))
        _check_range(entry, f"entry #{i}", path)
        points[i] = entry
    return points


def _from_csv(text: str, path: Path) -> np.ndarray:
    def check_header(header):
        names = [h.lower() for h in header]
        for name in ("x", "y", "z"):
            if names.count(name) != 1:
                raise InputError(f"line 1: CSV header must name each of the columns x, y, z once, got "
                                 f"{short_repr(header, 80)}", source=str(path))

    header, rows = csv_table(text, source=path, error=InputError, check_header=check_header)
    names = [h.lower() for h in header]
    columns = [names.index(k) for k in ("x", "y", "z")]
    points = []
    for line, row in rows:
        cells = [row[c].strip() for c in columns]
        if not all(_NUMBER.fullmatch(cell) for cell in cells):
            raise InputError(f"line {line}: expected numbers in columns x, y, z, got {short_repr(row, 80)}",
                             source=str(path))
        values = [float(cell) for cell in cells]
        _check_range(values, f"line {line}", path)
        points.append(values)
    return np.array(points, dtype=np.float64).reshape(-1, 3)


def _check_range(values, where: str, path: Path) -> None:
    for axis, value in zip("xyz", values):
        if not math.isfinite(value):
            raise InputError(f"{where}: coordinates must be finite numbers of metres, got {axis} = {value} (NaN, "
                             "Infinity, or a number too large for a float)", source=str(path))
        if abs(value) > config.COORDINATE_LIMIT:
            raise InputError(f"{where}: |{axis}| = {abs(value):g} m is beyond the coordinate limit of "
                             f"{config.COORDINATE_LIMIT:g} m", source=str(path))


def _is_number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)
