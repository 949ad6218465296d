"""Reading scene data key by key: every error names the offending key's path (``people[0].actions[2].reach``)."""

from __future__ import annotations

import math

import numpy as np

from depthguard.errors import SceneError
from depthguard.validation import NOT_A_NUMBER, short_repr

#: Marks a key without a default: it must be given.
REQUIRED = object()


class Section:
    """A mapping of the scene read key by key; errors name the key's path; :meth:`done` refuses unknown keys."""

    def __init__(self, data, path: str):
        if not isinstance(data, dict):
            raise SceneError(f"must be a mapping, got {kind_of(data)}", field=path or "scene")
        self.data = data
        self.path = path
        self.used: set[str] = set()

    def field(self, key: str) -> str:
        return f"{self.path}.{key}" if self.path else key

    def has(self, key: str) -> bool:
        return key in self.data

    def get(self, key: str, default=REQUIRED):
        self.used.add(key)
        if key not in self.data:
            if default is REQUIRED:
                raise SceneError("is missing", field=self.field(key))
            return default
        return self.data[key]

    def number(self, key, default=REQUIRED, positive=False, minimum=None, maximum=None) -> float:
        value = self.get(key, default)
        return as_number(value, self.field(key), positive=positive, minimum=minimum, maximum=maximum)

    def integer(self, key, default=REQUIRED, minimum=None) -> int:
        value = self.get(key, default)
        if isinstance(value, bool) or not isinstance(value, int):
            raise SceneError(f"must be an integer, got {value!r}", field=self.field(key))
        if minimum is not None and value < minimum:
            raise SceneError(f"must be >= {minimum}, got {value}", field=self.field(key))
        return value

    def boolean(self, key, default=REQUIRED) -> bool:
        value = self.get(key, default)
        if not isinstance(value, bool):
            raise SceneError(f"must be true or false, got {value!r}", field=self.field(key))
        return value

    def string(self, key, default=REQUIRED, choices=None) -> str:
        value = self.get(key, default)
        if not isinstance(value, str) or not value:
            raise SceneError(f"must be a non-empty string, got {value!r}", field=self.field(key))
        if choices is not None and value not in choices:
            raise SceneError(f"must be one of {', '.join(choices)}, got {value!r}", field=self.field(key))
        return value

    def vector(self, key, n: int, default=REQUIRED) -> np.ndarray:
        return as_vector(self.get(key, default), n, self.field(key))

    def points(self, key, n: int, default=REQUIRED) -> np.ndarray:
        value = self.get(key, default)
        if not isinstance(value, list):
            raise SceneError(f"must be a list of points of {n} numbers, got {value!r}", field=self.field(key))
        return np.array([as_vector(p, n, f"{self.field(key)}[{i}]") for i, p in enumerate(value)]).reshape(-1, n)

    def section(self, key, default=REQUIRED) -> "Section":
        value = self.get(key, default)
        return Section(value, self.field(key))

    def sections(self, key, default=REQUIRED) -> list["Section"]:
        value = self.get(key, default)
        if not isinstance(value, list):
            raise SceneError(f"must be a list of mappings, got {kind_of(value)}", field=self.field(key))
        return [Section(item, f"{self.field(key)}[{i}]") for i, item in enumerate(value)]

    def done(self) -> None:
        unknown = [key for key in self.data if key not in self.used]
        if unknown:
            raise SceneError(f"unknown key(s) {', '.join(map(repr, unknown))}", field=self.field(str(unknown[0])))


def kind_of(value) -> str:
    return "nothing" if value is None else type(value).__name__


def as_number(value, field: str, positive=False, minimum=None, maximum=None) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise SceneError(f"must be a number, got {short_repr(value)}", field=field)
    try:  # an integer beyond the float range is no number the simulation can use (docs/bad-input.md)
        value = float(value)
    except NOT_A_NUMBER:
        raise SceneError(f"must be a number within the float range (about 1.8e308), got {short_repr(value)}",
                         field=field) from None
    if not math.isfinite(value):
        raise SceneError(f"must be finite, got {value}", field=field)
    if positive and value <= 0:
        raise SceneError(f"must be positive, got {value}", field=field)
    if minimum is not None and value < minimum:
        raise SceneError(f"must be >= {minimum}, got {value}", field=field)
    if maximum is not None and value > maximum:
        raise SceneError(f"must be <= {maximum}, got {value}", field=field)
    return value


def as_vector(value, n: int, field: str) -> np.ndarray:
    if not isinstance(value, (list, tuple)) or len(value) != n:
        raise SceneError(f"must be a list of {n} numbers, got {value!r}", field=field)
    return np.array([as_number(x, f"{field}[{i}]") for i, x in enumerate(value)])


def new_name(section: Section, names: set) -> str:
    name = section.string("name")
    if "/" in name:
        raise SceneError(f"must not contain '/', got {name!r}", field=section.field("name"))
    if name in names:
        raise SceneError(f"{name!r} is used twice (objects and people share one namespace)",
                         field=section.field("name"))
    names.add(name)
    return name


def pose_of(section: Section) -> tuple[np.ndarray, float]:
    pose = (section.vector("center", 3), section.number("yaw", default=0.0))
    section.done()
    return pose
