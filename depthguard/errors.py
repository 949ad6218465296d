"""The exceptions depthguard raises for its users' mistakes.

Every error that concerns one camera names it and the offending field, so that a message read in a log is enough to
fix the rig or the driver::

    DepthguardError
    ├── RigError          a rig, camera or camera_info file is malformed or inconsistent
    ├── DepthImageError   a depth image cannot be read or does not fit its camera
    ├── InputError        points, options or other arguments are malformed
    ├── RobotError        a robot description (URDF, meshes, control points) is missing, malformed or unsupported
    ├── RenderingError    no headless OpenGL (EGL) context, or its OpenGL lacks what rendering needs
    └── SceneError        a simulation scene file (depthguard_lab.simulation) is malformed or describes the impossible

Three helpers phrase such errors alike everywhere: :func:`short_repr` (a value the user gave, cut short for a one-line
message), :func:`check_real` (a real number within a range, with its unit) and :func:`check_path` (a file name).
"""

from __future__ import annotations


class DepthguardError(Exception):
    """Base class of every error depthguard raises on purpose."""

    def __init__(self, message: str, *, camera: str | None = None, field: str | None = None, source: str | None = None):
        parts = [str(source)] if source else []
        if camera is not None:
            parts.append(f"camera {camera!r}")
        if field is not None:
            parts.append(f"field {field!r}")
        super().__init__(": ".join(parts + [message]))
        self.message = message
        self.camera = camera
        self.field = field
        self.source = source

    def with_source(self, source: str) -> "DepthguardError":
        """The same error, also naming the file it came from (for errors raised below a file reader)."""
        if self.source is not None:
            return self
        return type(self)(self.message, camera=self.camera, field=self.field, source=source)


class RigError(DepthguardError, ValueError):
    """A rig, camera or camera_info file is malformed or inconsistent."""


class DepthImageError(DepthguardError, ValueError):
    """A depth image cannot be read, or does not fit the camera it is given for."""


class InputError(DepthguardError, ValueError):
    """Points, options or other arguments are malformed (wrong shape, not finite, unknown policy)."""


class RobotError(DepthguardError, ValueError):
    """A robot description cannot be used: the URDF or a mesh it names is missing or malformed, a joint type is
    unsupported, or a control point names no link. The message names the file and the link or joint."""


class RenderingError(DepthguardError, RuntimeError):
    """No headless OpenGL context can be created (EGL or its system libraries missing), or the OpenGL it offers
    lacks what depthguard's renderer needs."""


class SceneError(DepthguardError, ValueError):
    """A simulation scene (depthguard_lab.simulation) is malformed, names something that does not exist, or asks for
    the impossible (an unreachable trajectory). ``field`` is the path of the offending key, e.g.
    ``people[0].actions[2].reach.target``."""


def short_repr(value, limit: int = 40) -> str:
    """``repr(value)`` cut to ``limit`` characters, for one-line messages about a value the user gave (a 400-digit
    number or a long string stays readable; an integer too long for Python to print is described)."""
    try:
        text = repr(value)
    except ValueError:  # more digits than Python converts to text (sys.get_int_max_str_digits)
        return f"an integer of about {int(value.bit_length() * 0.30103)} digits"
    text = " ".join(text.split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


def check_real(value, name: str, *, minimum: float | None = None, maximum: float | None = None,
               above_minimum: bool = False, unit: str = "", error: type[DepthguardError] | None = None,
               **context) -> float:
    """``value`` as a float after checking that it is a real number (not a bool, string, complex or array), finite,
    and in [``minimum``, ``maximum``] (``(minimum, maximum]`` with ``above_minimum``). Otherwise ``error`` (default
    :class:`InputError`) saying "``name`` must be ...", with ``context`` (``camera=``, ``field=``) passed on."""
    import math
    import numbers

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
    try:
        number = float(value)
    except (OverflowError, TypeError, ValueError):
        number = math.nan
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
    import numbers

    import numpy as np

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
    except (TypeError, ValueError):
        raise InputError(f"expected {n} numbers, got {short_repr(values)}", field=field_name) from None
    if array.dtype.kind not in "fiu":
        raise InputError(f"expected {n} real numbers{unit}, got {short_repr(values)} (dtype {array.dtype})",
                         field=field_name)
    return np.array(array, dtype=np.float64)


def check_path(path, what: str, error: type[DepthguardError] | None = None, **context):
    """``path`` as a :class:`pathlib.Path` after checking that it is a file name: a ``str`` or ``os.PathLike``
    without NUL characters (``None``, a number or bytes are refused with ``error``, default :class:`InputError`)."""
    import os
    from pathlib import Path

    error = InputError if error is None else error
    if not isinstance(path, (str, os.PathLike)):
        raise error(f"{what} must be a file name (str or path), got {short_repr(path)}", **context)
    text = os.fspath(path)
    if not isinstance(text, str) or "\0" in text or not text:
        raise error(f"{what} must be a non-empty file name without NUL characters, got {short_repr(path)}",
                    **context)
    return Path(text)
