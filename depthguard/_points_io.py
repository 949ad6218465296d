"""Reading control points from files: CSV with an ``x,y,z`` header, or JSON holding a list of [x, y, z]."""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np

from depthguard.errors import InputError


def load_points(path) -> np.ndarray:
    """(n, 3) float64 metres, world frame, from a ``.csv`` (header ``x,y,z``) or ``.json`` (list of [x, y, z]) file.

    Raises :class:`InputError` naming the file and the line or entry at fault.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")  # tolerate the byte-order mark spreadsheets write
    except OSError as exc:
        raise InputError(f"{path}: cannot read points file ({exc.strerror or exc})") from None
    except UnicodeDecodeError:
        raise InputError(f"{path}: points file is not text") from None
    if path.suffix.lower() == ".json":
        return _from_json(text, path)
    return _from_csv(text, path)


def _from_json(text: str, path: Path) -> np.ndarray:
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: malformed JSON ({exc.msg} at line {exc.lineno})") from None
    if not isinstance(data, list):
        raise InputError(f"{path}: expected a JSON list of [x, y, z], got {type(data).__name__}")
    points = []
    for i, entry in enumerate(data):
        if not (isinstance(entry, list) and len(entry) == 3 and all(_is_number(x) for x in entry)):
            raise InputError(f"{path}: entry #{i} must be [x, y, z] of finite numbers, got {entry!r}")
        points.append([float(x) for x in entry])
    return np.array(points, dtype=np.float64).reshape(-1, 3)


def _from_csv(text: str, path: Path) -> np.ndarray:
    rows = list(csv.reader(text.splitlines()))
    if not rows:
        raise InputError(f"{path}: empty CSV file; expected a header x,y,z")
    header = [h.strip().lower() for h in rows[0]]
    if not {"x", "y", "z"} <= set(header):
        raise InputError(f"{path}: line 1: CSV header must name columns x, y, z, got {rows[0]!r}")
    columns = [header.index(k) for k in ("x", "y", "z")]
    points = []
    for line, row in enumerate(rows[1:], start=2):
        if not row or all(not cell.strip() for cell in row):
            continue
        try:
            values = [float(row[c]) for c in columns]
        except (ValueError, IndexError):
            raise InputError(f"{path}: line {line}: expected numbers in columns x, y, z, got {row!r}") from None
        if not all(math.isfinite(v) for v in values):
            raise InputError(f"{path}: line {line}: coordinates must be finite, got {row!r}")
        points.append(values)
    return np.array(points, dtype=np.float64).reshape(-1, 3)


def _is_number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)
