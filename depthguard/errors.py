"""The exceptions depthguard raises for its users' mistakes.

Every error that concerns one camera names it and the offending field, so that a message read in a log is enough to
fix the rig or the driver::

    DepthguardError
    ├── RigError          a rig, camera or camera_info file is malformed or inconsistent
    ├── DepthImageError   a depth image cannot be read or does not fit its camera
    ├── InputError        points, options or other arguments are malformed
    ├── RobotError        a robot description (URDF, meshes, control points) is missing, malformed or unsupported
    ├── RenderingError    no headless OpenGL (EGL) context, or its OpenGL lacks what rendering needs
    ├── SceneError        a simulation scene file (depthguard_lab.simulation) is malformed or describes the impossible
    └── WriteError        a file or standard output could not be written (disk full, read-only, broken pipe)

The checks that raise them, one per kind of value, live in :mod:`depthguard.validation`.
"""

from __future__ import annotations


def one_line(text: str) -> str:
    """``text`` on one line: line breaks and other control characters (a file name may hold them) written as
    escapes, so that an error message is one line in a log (docs/bad-input.md)."""
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else c.encode("unicode_escape").decode("ascii") for c in text)


class DepthguardError(Exception):
    """Base class of every error depthguard raises on purpose. Its message is one line (:func:`one_line`)."""

    def __init__(self, message: str, *, camera: str | None = None, field: str | None = None, source: str | None = None):
        parts = [str(source)] if source else []
        if camera is not None:
            parts.append(f"camera {camera!r}")
        if field is not None:
            parts.append(f"field {field!r}")
        super().__init__(one_line(": ".join(parts + [str(message)])))
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


class WriteError(DepthguardError, OSError):
    """A file (or standard output) could not be written: the disk is full, the folder read-only or missing, the pipe
    closed. The message names the file (``source``) and says why, in one line; the file is left as it was
    (:func:`depthguard.io.files.atomic_write`). An ``OSError`` too, for callers that catch those."""

    def __str__(self) -> str:  # the one-line message, not OSError's "[Errno n] ..." form
        return str(self.args[0]) if self.args else ""
