"""Every check of a value a user gives depthguard, in one place: each ``check_*`` takes the value and the name of the
field it came from, and returns the value as depthguard uses it (a float, a float64 array, a Path) or raises a
:class:`~depthguard.DepthguardError` subclass naming that field (``InputError`` unless said otherwise). The public
functions of every package call these where a value enters, once; the kernels behind them trust what they get.

Files are checked where they are read (:mod:`depthguard.io.files` and each format's reader), since what is valid there
depends on the format.
"""

from __future__ import annotations

import math
import numbers
import os
from pathlib import Path

import numpy as np

from depthguard import config
from depthguard.errors import DepthguardError, InputError, RigError


#: What converting a value to a float (``float()``, ``np.array(..., dtype=np.float64)``) raises when the value is not
#: a real number (TypeError, ValueError) or is an integer beyond the float range (OverflowError): every conversion of
#: a user's value catches all three and names the field (docs/bad-input.md, "numbers beyond a float").
NOT_A_NUMBER = (TypeError, ValueError, OverflowError)


def short_repr(value, limit: int = 40) -> str:
    """``repr(value)`` cut to ``limit`` characters, for one-line messages about a value the user gave (a 400-digit
    number or a long string stays readable; an integer too long for Python to print is described)."""
    try:
        text = repr(value)
    except ValueError:  # more digits than Python converts to text (sys.get_int_max_str_digits)
        return f"an integer of about {int(value.bit_length() * 0.30103)} digits"
    text = " ".join(text.split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


def real_or_nan(value) -> float:
    """``value`` as a float when it is a real number (not a bool) that a float holds (+-inf included), else NaN:
    a string, a complex, an array, an integer beyond the float range. The callers' range checks refuse NaN."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        return math.nan
    try:
        return float(value)
    except NOT_A_NUMBER:
        return math.nan


def check_real(value, name: str, *, minimum: float | None = None, maximum: float | None = None,
               above_minimum: bool = False, unit: str = "", error: type[DepthguardError] | None = None,
               **context) -> float:
    """``value`` as a float after checking that it is a real number (not a bool, string, complex or array), finite,
    and in [``minimum``, ``maximum``] (``(minimum, maximum]`` with ``above_minimum``). Otherwise ``error`` (default
    :class:`InputError`) saying "``name`` must be ...", with ``context`` (``camera=``, ``field=``) passed on."""
    error = InputError if error is None else error
    if minimum is not None and maximum is not None:
        bounds = f" in {'(' if above_minimum else '['}{minimum:g}, {maximum:g}]"
    elif minimum is not None:
        bounds = f" {'>' if above_minimum else '>='} {minimum:g}"
    else:
        bounds = "" if maximum is None else f" <= {maximum:g}"
    wanted = f"a finite number{' of ' + unit if unit else ''}{bounds}"
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise error(f"{name} must be {wanted}, got {short_repr(value)}", **context)
    number = real_or_nan(value)
    if not math.isfinite(number) or (minimum is not None and (number <= minimum if above_minimum else
                                                               number < minimum)) or \
            (maximum is not None and number > maximum):
        raise error(f"{name} must be {wanted}, got {short_repr(value)}", **context)
    return number


def real_vector(values, n: int, field_name: str, unit: str = ""):
    """``values`` as a (new) float64 numpy array, refusing before conversion what is not real numbers (strings,
    complex, bools, objects, masked arrays; numpy would turn "0.1" or 1+2j into a float silently): otherwise
    :class:`InputError` naming ``field_name``. ``n`` is the expected count, for the message; the caller checks the
    shape and finiteness. ``unit`` (e.g. "radians or metres") goes into the message."""
    unit = f" ({unit})" if unit else ""
    if isinstance(values, (str, bytes)) or isinstance(values, np.ma.MaskedArray):
        raise InputError(f"expected {n} numbers, got {short_repr(values)}", field=field_name)
    if isinstance(values, (list, tuple)):  # numpy would read [0.1, True] as floats: look at each value
        for value in values:
            if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
                raise InputError(f"expected {n} real numbers{unit}, got {short_repr(value)} among them",
                                 field=field_name)
    try:
        array = np.asarray(values)
    except NOT_A_NUMBER:
        raise InputError(f"expected {n} numbers, got {short_repr(values)}", field=field_name) from None
    if array.dtype.kind not in "fiu":
        raise InputError(f"expected {n} real numbers{unit}, got {short_repr(values)} (dtype {array.dtype})",
                         field=field_name)
    return np.array(array, dtype=np.float64)


def check_path(path, what: str, error: type[DepthguardError] | None = None, **context):
    """``path`` as a :class:`pathlib.Path` after checking that it is a file name: a ``str`` or ``os.PathLike``
    without NUL characters (``None``, a number or bytes are refused with ``error``, default :class:`InputError`)."""
    error = InputError if error is None else error
    if not isinstance(path, (str, os.PathLike)):
        raise error(f"{what} must be a file name (str or path), got {short_repr(path)}", **context)
    text = os.fspath(path)
    if not isinstance(text, str) or "\0" in text or not text:
        raise error(f"{what} must be a non-empty file name without NUL characters, got {short_repr(path)}",
                    **context)
    return Path(text)


def check_count(values, limit: int, field: str, setting: str, error: type[DepthguardError] = InputError,
                **context) -> None:
    """Refuse, before anything is converted or allocated, an array or sequence ``values`` with more than ``limit``
    rows (its first dimension; every element of a flat one): :class:`InputError` naming ``field`` and the limit
    (``setting``, the config name that holds it); ``error`` and ``context`` (``camera=``) as in :func:`check_real`.
    What has no length passes (the caller's checks judge it)."""
    if isinstance(values, np.ndarray):
        rows = values.shape[0] if values.ndim else 1
    elif isinstance(values, (list, tuple)):
        rows = len(values)
    else:
        return
    if rows > limit:
        raise error(f"{rows} rows, more than the {limit} of {setting}", field=field, **context)


def check_points(points_world) -> np.ndarray:
    """Return control points as a C-contiguous (n, 3) float64 array (metres, world frame).

    Accepts a sequence or array of real numbers of shape (n, 3), or (3,) for a single point; an empty list or an
    array of shape (0,) or (0, 3) gives a (0, 3) array. Raises :class:`InputError` for anything else: a string,
    a masked array, complex, bool, object or text values, another shape (an (n, 0) array among them), a coordinate
    that is not finite or beyond ``config.COORDINATE_LIMIT`` metres (naming the point's index), more than
    ``config.MAX_QUERY_POINTS`` points (before any of them is converted).
    """
    if isinstance(points_world, (str, bytes)):
        raise InputError(f"points must be numbers of shape (n, 3) (metres, world frame), got a string "
                         f"{short_repr(points_world)}", field="points")
    if isinstance(points_world, np.ma.MaskedArray):
        raise InputError("points must not be a masked array: a masked coordinate has no value (pass the points you "
                         "mean, as a plain array)", field="points")
    check_count(points_world, config.MAX_QUERY_POINTS, "points", "config.MAX_QUERY_POINTS")
    try:
        array = np.asarray(points_world)
    except NOT_A_NUMBER as exc:  # ragged lists, objects numpy cannot read
        raise InputError(f"points must be numbers of shape (n, 3) ({' '.join(str(exc).split())[:120]})",
                         field="points") from None
    if array.dtype.kind not in "fiu":  # checked before converting: complex, bool, object and text never pass
        raise InputError(f"points must be real numbers (float or int), got dtype {array.dtype}", field="points")
    points = np.array(array, dtype=np.float64)
    if points.ndim == 1 and points.shape[0] in (0, 3):
        points = points.reshape(-1, 3)
    if points.ndim != 2 or points.shape[1] != 3:
        raise InputError(f"points must have shape (n, 3) (metres, world frame), got {points.shape}", field="points")
    bad = ~np.all(np.isfinite(points), axis=1)
    if bad.any():
        i = int(np.argmax(bad))
        raise InputError(f"point #{i} is not finite: {points[i].tolist()}", field="points")
    far = np.any(np.abs(points) > config.COORDINATE_LIMIT, axis=1)
    if far.any():
        i = int(np.argmax(far))
        raise InputError(f"point #{i} {points[i].tolist()} is beyond +-{config.COORDINATE_LIMIT:g} m "
                         "(config.COORDINATE_LIMIT)", field="points")
    return np.ascontiguousarray(points)


def check_options(rho: float, aggregate: str, unseen: str, method: str) -> float:
    """Raise :class:`InputError` for an unknown policy or a rho that is not a number of metres in
    [``config.RHO_MIN``, ``config.RHO_MAX``]; return rho as a float."""
    rho = check_real(rho, "rho", minimum=config.RHO_MIN, maximum=config.RHO_MAX, unit="metres", field="rho")
    for name, value, allowed in (("aggregate", aggregate, config.AGGREGATES),
                                 ("unseen", unseen, config.UNSEEN_POLICIES), ("method", method, config.METHODS)):
        if not isinstance(value, str) or value not in allowed:
            raise InputError(f"{name} must be one of {allowed}, got {short_repr(value)}", field=name)
    return rho


def check_transform(matrix, *, camera: str | None = None, field: str = "T_world_camera") -> np.ndarray:
    """Return ``matrix`` as a validated (4, 4) float64 rigid transform.

    Raises :class:`RigError` naming ``camera`` and ``field`` when the matrix is not 4x4, not finite, its last row is
    not ``[0, 0, 0, 1]``, or its rotation is not orthonormal with determinant +1 (within
    ``config.ROTATION_TOLERANCE``).
    """
    try:
        T = np.array(matrix, dtype=np.float64)
    except NOT_A_NUMBER as exc:
        raise RigError(f"not a 4x4 matrix of numbers ({exc})", camera=camera, field=field) from None
    if T.shape != (4, 4):
        raise RigError(f"expected a 4x4 matrix, got shape {T.shape}", camera=camera, field=field)
    if not np.all(np.isfinite(T)):
        raise RigError("contains NaN or infinity", camera=camera, field=field)
    if not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0], atol=config.ROTATION_TOLERANCE):
        raise RigError(f"last row must be [0, 0, 0, 1], got {T[3].tolist()}", camera=camera, field=field)
    R = T[:3, :3]
    off = np.abs(R.T @ R - np.eye(3)).max()
    det = np.linalg.det(R)
    if off > config.ROTATION_TOLERANCE or abs(det - 1.0) > config.ROTATION_TOLERANCE:
        raise RigError(
            f"rotation is not orthonormal with determinant +1 (max |R^T R - I| = {off:.3g}, det = {det:.6g})",
            camera=camera,
            field=field,
        )
    T[3] = (0.0, 0.0, 0.0, 1.0)
    return T


def check_limit(limit) -> float:
    """``limit`` (metres, >= 0, inf allowed) as a float, or :class:`InputError` naming ``limit``."""
    if isinstance(limit, float) and limit == math.inf:
        return limit
    return check_real(limit, "limit", minimum=0.0, unit="metres", field="limit")


def check_unseen(unseen) -> str:
    """The ``unseen`` policy of :func:`verdict`: "occupied" or "free", else InputError."""
    if unseen not in ("occupied", "free"):
        raise InputError(f"unseen must be 'occupied' (fail-safe) or 'free' (the paper's class B rule), got "
                         f"{unseen!r}", field="unseen")
    return unseen


def check_real_positive(value, name: str) -> float:
    """``value`` as a float if it is a finite real number > 0, else :class:`InputError` naming ``name``."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not 0.0 < float(value) < math.inf:
        raise InputError(f"{name} must be a finite number > 0 (metres), got {short_repr(value)}", field=name)
    return float(value)


def check_choice(value, name: str, allowed: tuple) -> str:
    if not isinstance(value, str) or value not in allowed:
        raise InputError(f"{name} must be one of {allowed}, got {short_repr(value)}", field=name)
    return value


def check_whole(value, name: str, maximum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not 0 <= value <= maximum:
        raise InputError(f"{name} must be a whole number in [0, {maximum}], got {short_repr(value)}", field=name)
    return int(value)
