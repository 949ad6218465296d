"""Campaign (issue 12, item 8), kind "depth arrays": bad depth images given to the Python API, one camera and fused.

Each image is the camera's true view of the wall (tests/campaign_support.py) with patches of values that mean "no
measurement" (NaN, +-inf, negative, 0, -0.0, subnormal, nearer than the minimum range, beyond the maximum range, huge)
or a valid depth nearer than the wall; then given as it is, as a masked array, cast to another dtype, or reshaped;
passed as a plain array, through ``dg.depth_image``, or as a ``dg.DepthImage`` built directly (which skips
``depth_image``'s checks).

Rule: either a DepthguardError, or the oracle for the wall at D holds. Pixels without a measurement are occupied
along their whole frustum from the minimum range (``invalid="occupied"``, the default), and a nearer surface hides
more, so neither can make the true answer larger. A secondary camera gets only such values: whatever it cannot see
it cannot clear.

- Masked arrays: a masked pixel holds no measurement (``numpy.ma``: the value is missing). The data under the mask
  is a lie, the wall as it stood before (``OLD_WALL``, farther than D): a library that reads through the mask sees a
  window in the wall, and points behind the wall in that window then get a positive distance (the oracle catches
  it). Also, for ``min``/``hybrid``, the answer must not exceed the answer with those pixels set to 0 (the explicit
  "no measurement") — the one comparison here between two of depthguard's own answers, as the brief asks.
- Wrong dtypes: safe reading: a dtype that has no reading as depth (bool, complex with a non-zero imaginary part, an
  object array holding None) must be refused; other dtypes may be refused or read (integers as depth_scale units or
  as metres: either reading of these images lies at or before the wall, or is invalid), and then the oracle holds.
- Wrong shapes must be refused, except (H, W, 1) and (1, H, W), which may also be read as the (H, W) image.
"""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

import depthguard as dg
from campaign_support import (
    H,
    OLD_WALL,
    TOL,
    CX,
    CY,
    FX,
    FY,
    W,
    Refused,
    call,
    campaign,
    check_result,
    fused_rig,
    point_sets,
    record,
    rigid_transforms,
    secondary_image,
    secondary_layouts,
    single_rig,
    surveyed,
    to_world,
    violation,
    wall_image,
    walls,
)

AGGREGATES = ["min", "mean", "hybrid"]

FLOAT_BAD = [("NaN", math.nan), ("+inf", math.inf), ("-inf", -math.inf), ("negative", -1.0), ("zero", 0.0),
             ("-0.0", -0.0), ("subnormal", 1e-45), ("below min range", 0.1), ("beyond max range", 4.5),
             ("1e30", 1e30), ("3.4e38", 3.4e38), ("1e308 (float64)", 1e308)]
U16_BAD = [("zero", 0), ("1 mm", 1), ("beyond max range", 4500), ("65535", 65535)]
SHAPES = ["(H, W, 1)", "(1, H, W)", "(W, H)", "(H, W+1)", "(H-1, W)", "(H, 0)", "(0, W)", "(H*W,)", "()",
          "(H, W, 3)", "(2, H, W)"]
MAY_READ_SHAPES = {"(H, W, 1)", "(1, H, W)"}


class Case:
    def __init__(self, **kw):
        self.__dict__.update(kw)


@st.composite
def rects(draw, max_count=4, min_count=0, min_side=1):
    out = []
    for _ in range(draw(st.integers(min_count, max_count))):
        v0 = draw(st.integers(0, H - min_side))
        u0 = draw(st.integers(0, W - min_side))
        v1 = draw(st.integers(v0 + min_side, H))
        u1 = draw(st.integers(u0 + min_side, W))
        out.append((v0, v1, u0, u1))
    return out


def _reshape(image, shape):
    wall = image.flat[0]
    return {
        "(H, W, 1)": lambda: image[..., None],
        "(1, H, W)": lambda: image[None],
        "(W, H)": lambda: np.ascontiguousarray(image.T),
        "(H, W+1)": lambda: np.concatenate([image, np.full((H, 1), wall, image.dtype)], axis=1),
        "(H-1, W)": lambda: image[:-1],
        "(H, 0)": lambda: image[:, :0],
        "(0, W)": lambda: image[:0],
        "(H*W,)": lambda: image.ravel(),
        "()": lambda: image[0, 0].copy() if hasattr(image[0, 0], "copy") else image[0, 0],
        "(H, W, 3)": lambda: np.stack([image] * 3, axis=-1),
        "(2, H, W)": lambda: np.stack([image] * 2),
    }[shape]()


@st.composite
def depth_cases(draw, base, image_kind: str, wall: float, secondary: bool):
    """A bad version of ``base`` (the camera's true view: float32 metres or uint16 millimetres)."""
    image = base.copy()
    labels = []
    for v0, v1, u0, u1 in draw(rects()):
        if draw(st.booleans()):
            # a valid depth nearer than the wall (hides more)
            if image_kind == "u16":
                value = draw(st.integers(300, max(300, int(image[v0:v1, u0:u1].min()) - 1)))
            else:
                value = np.float32(draw(st.floats(0.3, max(0.3, float(np.nanmin(image[v0:v1, u0:u1])) - 1e-3))))
            labels.append("nearer")
        else:
            name, value = draw(st.sampled_from(U16_BAD if image_kind == "u16" else FLOAT_BAD))
            labels.append(name)
            if name == "1e308 (float64)":
                image = image.astype(np.float64)
        image[v0:v1, u0:u1] = value
    form = draw(st.sampled_from(["native", "native", "masked", "masked", "dtype", "dtype", "shape"]))
    via = draw(st.sampled_from(["array", "depth_image", "DepthImage"]))
    case = Case(data=image, via=via, must_error=False, wall=wall, zero=None, masked_rects=[], form=form,
                scale=0.001 if image_kind == "u16" else 1.0, labels=labels)
    if form == "masked":
        # secondary: a large mask (its lie must cover whole cells to clear them); principal: a few windows
        masked = draw(rects(min_count=1, max_count=1, min_side=24)) if secondary else draw(rects(min_count=1))
        mask = np.zeros((H, W), bool)
        lie = image.copy()
        for v0, v1, u0, u1 in masked:
            mask[v0:v1, u0:u1] = True
        lie[mask] = 3900 if image_kind == "u16" else OLD_WALL
        zero = image.copy()
        zero[mask] = 0
        case.data = np.ma.array(lie, mask=mask)
        case.zero = zero
        case.masked_rects = masked
        labels.append("masked")
    elif form == "dtype":
        if image_kind == "u16":
            dtype = draw(st.sampled_from(["int8", "int16", "int32", "int64", "uint8", "uint32", "uint64", "bool"]))
            case.data = image.astype(dtype)
            case.must_error = dtype == "bool"
        else:
            dtype = draw(st.sampled_from(["float64", "float16", ">f4", "complex64", "complex64+1j", "object",
                                          "object+None", "str", "bool"]))
            if dtype == "float16":
                case.data = image.astype(np.float16)
                case.wall = float(np.float16(wall))  # the wall the image says: float16 rounds D
            elif dtype == "complex64+1j":
                case.data = image.astype(np.complex64) + np.complex64(0.5j)
                case.must_error = True
            elif dtype == "object+None":
                case.data = image.astype(object)
                case.data[0, 0] = None
                case.must_error = True
            elif dtype == "str":
                case.data = image.astype(str)
            else:
                case.data = image.astype(dtype)
                case.must_error = dtype == "bool"
            case.scale = 1.0
        labels.append(f"dtype {dtype}")
    elif form == "shape":
        shape = draw(st.sampled_from(SHAPES))
        case.data = _reshape(image, shape)
        case.must_error = shape not in MAY_READ_SHAPES
        labels.append(f"shape {shape}")
    case.description = f"{form}, via {via}: {', '.join(labels) or 'clean'}"
    case.tag = f"{labels[-1] if form != 'native' else 'native'} via {via}"
    return case


def _frame(case, camera_name, data=None):
    data = case.data if data is None else data
    if case.via == "array":
        return lambda rig: data
    if case.via == "depth_image":
        return lambda rig: dg.depth_image(data, rig.cameras[camera_name])
    return lambda rig: dg.DepthImage(camera=camera_name, data=data, depth_scale=case.scale, timestamp=None)


def _targets(case, wall, secondary):
    """Optical-frame points behind the wall where a masked lie would open a window (their exact distance is 0)."""
    out = []
    far = min(OLD_WALL, 3.6)
    if wall > far - 0.1:
        return out
    z = 0.5 * (wall + far)
    if secondary:
        for a in (-0.4, 0.0, 0.4):
            for b in (-0.3, 0.0, 0.3):
                out.append((a * z, b * z, z))
        return out
    for v0, v1, u0, u1 in case.masked_rects:
        u, v = 0.5 * (u0 + u1 - 1), 0.5 * (v0 + v1 - 1)
        out.append(((u - CX) / FX * z, (v - CY) / FY * z, z))
    return out


def _run(kind, case, rig, frames_for, points_camera, G, rho, aggregate, wall):
    """frames_for(data) -> {name: frame builder}; applies the rule to the case."""
    points_world = to_world(G, points_camera)

    def query(data=None):
        frames = {name: build(rig) for name, build in frames_for(data).items()}
        return dg.DistanceMonitor(rig, rho=rho, aggregate=aggregate).query(frames, points_world)

    result = call(kind, query, tag=case.tag)
    if isinstance(result, Refused):
        record(kind, result.label)
        return
    if case.must_error:
        violation(kind, f"{case.tag}: accepted", f"{case.description}: distances {result.distance.tolist()}")
    outcome = check_result(kind, result, points_camera, case.wall, rho, aggregate, context=case.description,
                           tag=case.tag)
    if case.zero is not None and aggregate != "mean":
        zero = call(kind, lambda: query(case.zero), tag=case.tag + " (zeros)")
        if not isinstance(zero, Refused):
            worse = result.distance > zero.distance + TOL
            if worse.any():
                i = int(np.argmax(worse))
                violation(kind, "masked pixels count for more than no measurement",
                          f"{case.description}: point {points_camera[i].tolist()}: masked {result.distance[i]!r}, "
                          f"zeros {zero.distance[i]!r}")
    record(kind, outcome)


@campaign(80)
@given(G=rigid_transforms(), wall=walls(), data=st.data(), rho=st.floats(0.05, 1.5),
       aggregate=st.sampled_from(AGGREGATES))
@surveyed
def test_bad_depth_single_camera(G, wall, data, rho, aggregate):
    kind = "depth: single"
    image_kind, value, D = wall
    case = data.draw(depth_cases(wall_image(value, image_kind), image_kind, D, secondary=False))
    points = np.array(data.draw(point_sets(D)) + _targets(case, D, False)).reshape(-1, 3)
    rig = single_rig(G)
    _run(kind, case, rig, lambda d: {"p": _frame(case, "p", d)}, points, G, rho, aggregate, D)


@campaign(60)
@given(G=rigid_transforms(), wall=walls(hi_mm=3400), layout=secondary_layouts(), secondary_kind=st.sampled_from(
    ["f32", "u16"]), bad=st.sampled_from(["principal", "secondary"]), data=st.data(), rho=st.floats(0.05, 1.0),
       aggregate=st.sampled_from(AGGREGATES))
@surveyed
def test_bad_depth_fused(G, wall, layout, secondary_kind, bad, data, rho, aggregate):
    kind = f"depth: fused {bad}"
    image_kind, value, D = wall
    principal = wall_image(value, image_kind)
    secondary = secondary_image(layout, D, secondary_kind)
    if bad == "principal":
        case = data.draw(depth_cases(principal, image_kind, D, secondary=False))
    else:
        case = data.draw(depth_cases(secondary, secondary_kind, D, secondary=True))
        case.wall = D  # the secondary's dtype never changes the wall's true place
    points = np.array(data.draw(point_sets(D)) + _targets(case, D, bad == "secondary")).reshape(-1, 3)
    rig = fused_rig(G, layout)

    def frames_for(d):
        if bad == "principal":
            return {"p": _frame(case, "p", d), "s": lambda rig: secondary}
        return {"p": lambda rig: principal, "s": _frame(case, "s", d)}

    _run(kind, case, rig, frames_for, points, G, rho, aggregate, D)
