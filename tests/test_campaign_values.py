"""Campaign (issue 12, item 8), kinds "rho" and "points": bad surveillance radii and bad control points given to the
Python API, one camera and fused, with the ``min``, ``mean`` and ``hybrid`` aggregations.

Rule: either a DepthguardError, or the oracle (tests/campaign_support.py) holds for what the input denotes.

- rho: tiny (1e-200, 1e-12, subnormals), huge (1e160, 1e308), NaN, +-inf, negative, 0, -0.0, strings, bytes, bool,
  None, lists, numpy scalars, complex, Decimal, Fraction. An accepted rho is read as the real number it denotes
  (bool as 0/1): the oracle then holds with that rho, ``inf`` only where the exact distance is at least rho (for NaN
  or a negative rho: never where the exact distance is 0), and a point inside the obstacle gets 0 whatever rho. An
  accepted rho that denotes no real number (a list, None, "abc") is a violation.
- points: coordinates huge (1e160, 1e308), NaN, +-inf, subnormal, -0.0; dtypes (float32/16, big-endian, int8/16/64,
  uint64, bool, complex, object, str, Decimal, Fraction, numpy scalars); masked arrays; shapes. What an input
  denotes is what numpy's float64 conversion of it gives (an int8 array denotes its int8 values); the oracle is
  computed from that. A point with a non-finite or huge coordinate lies outside the bounded free space P: exact
  distance 0, so it must get 0 (or the input be refused). Safe readings: a masked coordinate is unknown, so its point
  must get 0 or the input be refused (the data under the mask is a point in free space, which a library that reads
  through the mask would answer); a complex coordinate with a non-zero imaginary part, an object array holding None
  or a non-number, a shape (n, 0) with n > 0, a 3-D array, a scalar or a ragged list must be refused (answering
  them would answer for points the caller did not give). Empty inputs ((0, 3), (0,), [], (0, 0)) may be refused or
  give an empty result.
"""

from __future__ import annotations

import math
from decimal import Decimal
from fractions import Fraction

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

import depthguard as dg
from campaign_support import (
    Refused,
    call,
    campaign,
    check_result,
    fused_rig,
    nasty_floats,
    point_sets,
    real_value,
    record,
    rigid_transforms,
    secondary_image,
    secondary_layouts,
    single_rig,
    surveyed,
    to_camera,
    to_world,
    violation,
    wall_image,
    walls,
)

AGGREGATES = ["min", "mean", "hybrid"]

# --------------------------------------------------------------------------------------------------------- rho

RHO_SPECIALS = [1e-200, 1e-12, 5e-324, 1e-310, 2.2250738585072014e-308, 1e-6, 1e160, 1e308, 1.7976931348623157e308,
                1e6, math.nan, math.inf, -math.inf, -1.0, -0.4, 0.0, -0.0, "0.4", "nan", "inf", "abc", b"0.4", True,
                False, None, [0.4], (0.4,), np.array([0.4]), np.float32(0.4), np.float64(math.nan), np.float16(0.4),
                np.int64(1), 1, 0, complex(0.4, 0.0), complex(0.4, 1.0), Decimal("0.4"), Decimal("NaN"),
                Fraction(2, 5), np.float64(1e-200)]


def rho_values():
    return st.one_of(st.sampled_from(RHO_SPECIALS), st.floats(allow_nan=True, allow_infinity=True),
                     st.floats(1e-3, 3.0))


def _scene(fused, G, wall, layout, image_kind, value):
    if fused:
        return fused_rig(G, layout), {"p": wall_image(value, image_kind), "s": secondary_image(layout, wall, "f32")}
    return single_rig(G), {"p": wall_image(value, image_kind)}


@campaign(60)
@given(G=rigid_transforms(), wall=walls(hi_mm=3400), layout=secondary_layouts(), fused=st.booleans(),
       via=st.sampled_from(["monitor", "single_camera_distances"]), rho=rho_values(), data=st.data(),
       aggregate=st.sampled_from(AGGREGATES))
@surveyed
def test_bad_rho(G, wall, layout, fused, via, rho, data, aggregate):
    if fused:
        via = "monitor"
    kind = f"rho: {'fused' if fused else 'single'}"
    image_kind, value, D = wall
    points = np.array(data.draw(point_sets(D)) + [(0.0, 0.0, D + 0.2)])  # one point surely behind the wall
    rig, frames = _scene(fused, G, D, layout, image_kind, value)
    world = to_world(G, points)

    def query():
        if via == "monitor":
            return dg.DistanceMonitor(rig, rho=rho, aggregate=aggregate).query(frames, world)
        occupancy = dg.prepare_depth(dg.depth_image(frames["p"], rig.cameras["p"]), rig.cameras["p"])
        return dg.single_camera_distances(occupancy, world, rho, aggregate)

    tag = f"rho {rho!r} via {via}"
    result = call(kind, query, tag=tag)
    if isinstance(result, Refused):
        record(kind, result.label)
        return
    value_ = real_value(rho)
    if value_ is None:
        violation(kind, f"accepted a rho that is not a number ({type(rho).__name__})", tag)
    record(kind, check_result(kind, result, points, D, value_, aggregate, context=tag, tag=f"rho {rho!r}"))


# ------------------------------------------------------------------------------------------------------ points

FORMS = ["float64", "float64", "list", "tuple", "float32", "float16", ">f8", "F-order", "strided", "int8", "int16",
         "int64", "uint64", "bool", "complex", "complex+1j", "object", "object+None", "object+str", "str", "Decimal",
         "Fraction", "numpy scalars", "masked", "masked"]
SHAPES = ["(n, 3)"] * 6 + ["(3,)", "(n, 0)", "(0, 3)", "(0,)", "[]", "(0, 0)", "(n, 2)", "(n, 4)", "(n, 3, 1)",
                          "(1, n, 3)", "(3, n)", "scalar", "ragged"]
MUST_ERROR_FORMS = {"complex+1j", "object+None", "object+str"}
MUST_ERROR_SHAPES = {"(n, 0)", "(n, 2)", "(n, 4)", "(n, 3, 1)", "(1, n, 3)", "scalar", "ragged"}
EMPTY_SHAPES = {"(0, 3)", "(0,)", "[]", "(0, 0)"}


class PointsCase:
    def __init__(self, **kw):
        self.__dict__.update(kw)


def _shaped(world: np.ndarray, shape: str):
    """The float64 array (or nested list, for ragged) of the given shape, and the (m, 3) rows it denotes or None."""
    n = len(world)
    if shape == "(n, 3)":
        return world, world
    if shape == "(3,)":
        return world[0].copy(), world[:1]
    if shape in ("(0, 3)", "[]"):
        return np.zeros((0, 3)), np.zeros((0, 3))
    if shape == "(0,)":
        return np.zeros((0,)), np.zeros((0, 3))
    if shape == "(0, 0)":
        return np.zeros((0, 0)), np.zeros((0, 3))
    if shape == "(n, 0)":
        return world[:, :0], None
    if shape == "(n, 2)":
        return world[:, :2].copy(), None
    if shape == "(n, 4)":
        return np.concatenate([world, np.ones((n, 1))], axis=1), None
    if shape == "(n, 3, 1)":
        return world[..., None].copy(), None
    if shape == "(1, n, 3)":
        return world[None].copy(), None
    if shape == "(3, n)":
        transposed = np.ascontiguousarray(world.T)
        return transposed, (transposed if n == 3 else None)
    if shape == "scalar":
        return np.float64(world[0, 0]), None
    if shape == "ragged":
        rows = [list(r) for r in world] + [list(world[0, :2])]
        return rows, None
    raise AssertionError(shape)


def _nested(array, convert):
    if isinstance(array, list):
        return [_nested(a, convert) for a in array]
    array = np.asarray(array)
    if array.ndim == 0:
        return convert(float(array))
    return [_nested(a, convert) for a in array]


@st.composite
def point_inputs(draw, G, wall):
    cam = np.array(draw(point_sets(wall, max_size=5)))
    world = to_world(G, cam)
    n = len(world)
    for _ in range(draw(st.integers(0, 2))):
        world[draw(st.integers(0, n - 1)), draw(st.integers(0, 2))] = draw(nasty_floats())
    form = draw(st.sampled_from(FORMS))
    shape = draw(st.sampled_from(SHAPES))
    if shape == "ragged" and form not in ("list", "tuple", "Decimal", "Fraction", "numpy scalars"):
        form = "list"
    shaped, rows = _shaped(world, shape)
    must_error = shape in MUST_ERROR_SHAPES or (shape == "(3, n)" and n != 3)
    unknown = None
    array = np.asarray(shaped, dtype=np.float64) if shape != "ragged" else None
    with np.errstate(all="ignore"):
        if form == "float64":
            obj = array
        elif form in ("list", "tuple"):
            obj = _nested(shaped, float)
            if form == "tuple":
                obj = tuple(tuple(r) if isinstance(r, list) else r for r in obj) if isinstance(obj, list) else obj
        elif form in ("float32", "float16", ">f8", "int8", "int16", "int64", "uint64", "bool"):
            obj = array.astype(form)
        elif form == "F-order":
            obj = np.asfortranarray(array)
        elif form == "strided":
            big = np.repeat(array, 2, axis=0) if array.ndim >= 1 and array.size else array
            obj = big[::2] if array.ndim >= 1 and array.size else array
        elif form == "complex":
            obj = array.astype(np.complex128)
        elif form == "complex+1j":
            obj = array.astype(np.complex128) + 1j
            must_error = must_error or array.size > 0  # an entry with a non-zero imaginary part
        elif form == "object":
            obj = array.astype(object)
        elif form in ("object+None", "object+str"):
            obj = array.astype(object)
            if obj.size:
                obj.flat[0] = None if form == "object+None" else "abc"
                must_error = True
        elif form == "str":
            obj = array.astype(str)
        elif form == "Decimal":
            obj = _nested(shaped, lambda x: Decimal(repr(x)))
        elif form == "Fraction":
            obj = _nested(shaped, lambda x: Fraction(x) if math.isfinite(x) else x)
        elif form == "numpy scalars":
            obj = _nested(shaped, np.float32)
        elif form == "masked":
            mask = np.zeros(array.shape, bool)
            if array.size:
                for _ in range(draw(st.integers(1, 3))):
                    mask.flat[draw(st.integers(0, array.size - 1))] = True
            lie = np.asarray(to_world(G, [(0.0, 0.0, 0.5 * wall)])[0])
            data = array.copy()
            if data.ndim == 2 and data.shape[1] == 3:
                data[mask] = np.broadcast_to(lie, data.shape)[mask]
            obj = np.ma.array(data, mask=mask)
            if rows is not None and rows.shape == array.shape and array.ndim == 2:
                unknown = mask.any(axis=1)
        else:
            raise AssertionError(form)
    if rows is not None and not (form in MUST_ERROR_FORMS and must_error):
        # what the input denotes: its own float64 conversion (int8 wraps, float16 rounds, ...)
        with np.errstate(all="ignore"):
            if isinstance(obj, np.ma.MaskedArray):
                denoted = np.asarray(obj.data, dtype=np.float64)
            elif isinstance(obj, np.ndarray) and obj.dtype.kind == "c":
                denoted = obj.real.astype(np.float64)
            else:
                denoted = np.array(_nested(obj, float) if not isinstance(obj, np.ndarray) else obj.astype(np.float64),
                                   dtype=np.float64)
        rows = denoted.reshape(-1, 3) if shape != "(3,)" else denoted.reshape(1, 3)
    return PointsCase(obj=obj, rows=rows, must_error=must_error, unknown=unknown, empty=shape in EMPTY_SHAPES,
                      tag=f"{form} {shape}")


@campaign(100)
@given(G=rigid_transforms(), wall=walls(hi_mm=3400), layout=secondary_layouts(), fused=st.booleans(),
       data=st.data(), rho=st.floats(0.05, 1.5), aggregate=st.sampled_from(AGGREGATES))
@surveyed
def test_bad_points(G, wall, layout, fused, data, rho, aggregate):
    kind = f"points: {'fused' if fused else 'single'}"
    image_kind, value, D = wall
    case = data.draw(point_inputs(G, D))
    rig, frames = _scene(fused, G, D, layout, image_kind, value)
    result = call(kind, lambda: dg.DistanceMonitor(rig, rho=rho, aggregate=aggregate).query(frames, case.obj),
                  tag=case.tag)
    if isinstance(result, Refused):
        record(kind, result.label)
        return
    if case.must_error:
        violation(kind, f"{case.tag}: accepted", f"input {case.obj!r:.300}: distances {result.distance.tolist()}")
    if case.empty:
        if len(result.distance) != 0:
            violation(kind, f"{case.tag}: empty input, non-empty result", f"{len(result.distance)} results")
        record(kind, "empty input: empty result")
        return
    if case.rows is None:  # (3, n) with n == 3 only reaches here with rows set
        raise AssertionError(case.tag)
    record(kind, check_result(kind, result, to_camera(G, case.rows), D, rho, aggregate, unknown=case.unknown,
                              context=f"{case.tag}: {case.obj!r:.300}", tag=case.tag))
