"""Campaign (issue 12, item 8), kind "API arguments": arguments of the wrong type or value given to the Python API.

Every case below must raise a DepthguardError: a string, an int or None where a rig, a map, a robot, a number of
seconds is expected; ``principals="cam"`` (a string is not a list of names: it must not be read as the cameras 'c',
'a', 'm', which this rig has); unknown or non-string policy names; bad hole_pixels, fusion_margin, fusion_pixels,
self_filter options; frames and ``now`` of the wrong type. Safe readings: an option value that is unknown or of the
wrong type is refused even when the option is not used by this monitor (a typo must not be silently ignored), and a
bool is not a number of seconds, metres or pixels.

The table is swept whole (``test_api_table``, one test per case) and drawn from by a strategy that also varies the
rest of the call (``test_api_strategy``).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import depthguard as dg
from campaign_support import (
    FILE_SECONDARY,
    Refused,
    SurveyedViolation,
    call,
    camera,
    campaign,
    fused_rig,
    record,
    secondary_image,
    single_rig,
    surveyed,
    violation,
    wall_image,
)


class Env:
    def __init__(self):
        self.rig = single_rig(np.eye(4))
        self.rig2 = fused_rig(np.eye(4), FILE_SECONDARY)
        cams = {}
        for i, name in enumerate(["cam", "c", "a", "m"]):
            T = np.eye(4)
            T[0, 3] = 0.05 * i
            cams[name] = camera(name, T)
        self.rig_cam = dg.Rig(cams, principal="cam")
        self.image = wall_image(2.0, "f32")
        self.frames = {"p": self.image}
        self.frames2 = {"p": self.image, "s": secondary_image(FILE_SECONDARY, 2.0, "f32")}
        self.frames_cam = {name: self.image for name in cams}
        self.points = np.array([[0.0, 0.0, 1.0], [0.2, 0.1, 1.5]])
        from depthguard.depthgrid import build_map

        self.map_p = build_map(self.rig2, "p")
        self.map_s = build_map(self.rig2, "s")


_ENV = None


def env() -> Env:
    global _ENV
    if _ENV is None:
        _ENV = Env()
    return _ENV


def monitor(rig_attr="rig", **kw):
    return lambda e: dg.DistanceMonitor(getattr(e, rig_attr), **kw).query(
        {"rig": e.frames, "rig2": e.frames2, "rig_cam": e.frames_cam}[rig_attr], e.points)


def _frames_query(frames, **kw):
    return lambda e: dg.DistanceMonitor(e.rig).query(frames(e) if callable(frames) else frames, e.points, **kw)


CASES = {
    # the rig
    "rig='rig.yaml'": lambda e: dg.DistanceMonitor("rig.yaml"),
    "rig=5": lambda e: dg.DistanceMonitor(5),
    "rig=None": lambda e: dg.DistanceMonitor(None),
    "rig=dict": lambda e: dg.DistanceMonitor(e.rig.to_dict()),
    "rig=PinholeCamera": lambda e: dg.DistanceMonitor(e.rig.cameras["p"]),
    "rig=[camera]": lambda e: dg.DistanceMonitor([e.rig.cameras["p"]]),
    # policies
    "aggregate='MIN'": monitor(aggregate="MIN"),
    "aggregate='max'": monitor(aggregate="max"),
    "aggregate=''": monitor(aggregate=""),
    "aggregate=None": monitor(aggregate=None),
    "aggregate=1": monitor(aggregate=1),
    "aggregate=['min']": monitor(aggregate=["min"]),
    "aggregate=array(['min', 'mean'])": monitor(aggregate=np.array(["min", "mean"])),
    "aggregate=b'min'": monitor(aggregate=b"min"),
    "invalid='neighbours'": monitor(invalid="neighbours"),
    "invalid='occupied '": monitor(invalid="occupied "),
    "invalid=None": monitor(invalid=None),
    "invalid=array(['free'])": monitor(invalid=np.array(["free", "occupied"])),
    "unseen='Occupied'": monitor(unseen="Occupied"),
    "unseen='ignore'": monitor(unseen="ignore"),
    "unseen=None": monitor(unseen=None),
    "unseen=True": monitor(unseen=True),
    "method='Exact'": monitor(method="Exact"),
    "method=None": monitor(method=None),
    # rho (the rho kind has many more)
    "rho='0.4 m'": monitor(rho="0.4 m"),
    "rho=None": monitor(rho=None),
    "rho=[0.4]": monitor(rho=[0.4]),
    "rho=nan": monitor(rho=math.nan),
    # max_age
    "max_age='0.1'": lambda e: dg.DistanceMonitor(e.rig, max_age="0.1"),
    "max_age=True": lambda e: dg.DistanceMonitor(e.rig, max_age=True),
    "max_age=0": lambda e: dg.DistanceMonitor(e.rig, max_age=0),
    "max_age=-1": lambda e: dg.DistanceMonitor(e.rig, max_age=-1),
    "max_age=nan": lambda e: dg.DistanceMonitor(e.rig, max_age=math.nan),
    "max_age=inf": lambda e: dg.DistanceMonitor(e.rig, max_age=math.inf),
    "max_age=[0.1]": lambda e: dg.DistanceMonitor(e.rig, max_age=[0.1]),
    "max_age=0.1j": lambda e: dg.DistanceMonitor(e.rig, max_age=0.1j),
    "max_age=np.nan": lambda e: dg.DistanceMonitor(e.rig, max_age=np.float64("nan")),
    # hole_pixels
    "hole_pixels=-1": lambda e: dg.DistanceMonitor(e.rig, hole_pixels=-1),
    "hole_pixels=1.5": lambda e: dg.DistanceMonitor(e.rig, hole_pixels=1.5),
    "hole_pixels='64'": lambda e: dg.DistanceMonitor(e.rig, hole_pixels="64"),
    "hole_pixels=True": lambda e: dg.DistanceMonitor(e.rig, hole_pixels=True),
    "hole_pixels=None": lambda e: dg.DistanceMonitor(e.rig, hole_pixels=None),
    "hole_pixels=10**30 (neighbors)": lambda e: dg.DistanceMonitor(e.rig, invalid="neighbors", hole_pixels=10 ** 30)
    .query({"p": np.where(np.arange(e.image.size).reshape(e.image.shape) % 7 == 0, np.nan, e.image)
            .astype(np.float32)}, e.points),
    "hole_pixels=np.float64(64)": lambda e: dg.DistanceMonitor(e.rig, hole_pixels=np.float64(64)),
    # robot
    "robot='iiwa'": lambda e: dg.DistanceMonitor(e.rig, robot="iiwa"),
    "robot=5": lambda e: dg.DistanceMonitor(e.rig, robot=5),
    "robot=object()": lambda e: dg.DistanceMonitor(e.rig, robot=object()),
    "self_filter='mesh' (unknown)": lambda e: dg.DistanceMonitor(e.rig, self_filter="mesh"),
    "self_filter=None": lambda e: dg.DistanceMonitor(e.rig, self_filter=None),
    "self_filter_tolerance=nan": lambda e: dg.DistanceMonitor(e.rig, self_filter_tolerance=math.nan),
    "self_filter_tolerance=-1": lambda e: dg.DistanceMonitor(e.rig, self_filter_tolerance=-1.0),
    "self_filter_tolerance='x'": lambda e: dg.DistanceMonitor(e.rig, self_filter_tolerance="x"),
    # principals
    "principals='cam'": monitor("rig_cam", principals="cam"),
    "principals=[]": monitor("rig2", principals=[]),
    "principals=['nope']": monitor("rig2", principals=["nope"]),
    "principals=[5]": monitor("rig2", principals=[5]),
    "principals=5": monitor("rig2", principals=5),
    "principals=[None]": monitor("rig2", principals=[None]),
    "principals=b'p'": monitor("rig2", principals=b"p"),
    # maps
    "maps='map.npz'": monitor("rig2", maps="map.npz"),
    "maps=5": monitor("rig2", maps=5),
    "maps=[map]": lambda e: dg.DistanceMonitor(e.rig2, maps=[e.map_p]).query(e.frames2, e.points),
    "maps={'p': 'map.npz'}": monitor("rig2", maps={"p": "map.npz"}),
    "maps={'p': None}": monitor("rig2", maps={"p": None}),
    "maps={'p': map of principal s}": lambda e: dg.DistanceMonitor(e.rig2, maps={"p": e.map_s}).query(e.frames2,
                                                                                                      e.points),
    "maps={'p': map of another rig}": lambda e: dg.DistanceMonitor(e.rig2, maps={"p": __import__(
        "depthguard.depthgrid", fromlist=["build_map"]).build_map(e.rig_cam, "cam")}),
    # fusion options
    "fusion_margin=nan": monitor("rig2", fusion_margin=math.nan),
    "fusion_margin=-1": monitor("rig2", fusion_margin=-1.0),
    "fusion_margin=inf": monitor("rig2", fusion_margin=math.inf),
    "fusion_margin='0.01'": monitor("rig2", fusion_margin="0.01"),
    "fusion_margin=None": monitor("rig2", fusion_margin=None),
    "fusion_margin=True": monitor("rig2", fusion_margin=True),
    "fusion_pixels=-1": monitor("rig2", fusion_pixels=-1),
    "fusion_pixels=1.5": monitor("rig2", fusion_pixels=1.5),
    "fusion_pixels='1'": monitor("rig2", fusion_pixels="1"),
    "fusion_pixels=True": monitor("rig2", fusion_pixels=True),
    "fusion_pixels=None": monitor("rig2", fusion_pixels=None),
    # query: frames
    "frames=None": _frames_query(None),
    "frames=[]": _frames_query([]),
    "frames='p'": _frames_query("p"),
    "frames=[('p', image)]": _frames_query(lambda e: [("p", e.image)]),
    "frames={'p': None}": _frames_query({"p": None}),
    "frames={'p': 'depth.png'}": _frames_query({"p": "depth.png"}),
    "frames={5: image}": _frames_query(lambda e: {5: e.image}),
    "frames={'zzz': image}": _frames_query(lambda e: {"zzz": e.image}),
    "frames={'p': DepthImage of camera s}": _frames_query(
        lambda e: {"p": dg.depth_image(e.image, e.rig2.cameras["s"])}),
    # query: now
    "now='1.0'": lambda e: dg.DistanceMonitor(e.rig, max_age=0.1).query(
        {"p": dg.depth_image(e.image, e.rig.cameras["p"], 1.0)}, e.points, now="1.0"),
    "now=[1.0]": lambda e: dg.DistanceMonitor(e.rig, max_age=0.1).query(
        {"p": dg.depth_image(e.image, e.rig.cameras["p"], 1.0)}, e.points, now=[1.0]),
    "now=1j": lambda e: dg.DistanceMonitor(e.rig, max_age=0.1).query(
        {"p": dg.depth_image(e.image, e.rig.cameras["p"], 1.0)}, e.points, now=1j),
    "now=True": lambda e: dg.DistanceMonitor(e.rig, max_age=0.1).query(
        {"p": dg.depth_image(e.image, e.rig.cameras["p"], 1.0)}, e.points, now=True),
    "now=None with max_age": lambda e: dg.DistanceMonitor(e.rig, max_age=0.1).query(
        {"p": dg.depth_image(e.image, e.rig.cameras["p"], 1.0)}, e.points, now=None),
    # other public functions
    "depth_image(timestamp='1.0')": lambda e: dg.depth_image(e.image, e.rig.cameras["p"], "1.0"),
    "depth_image(timestamp=True)": lambda e: dg.depth_image(e.image, e.rig.cameras["p"], True),
    "depth_image(camera='p')": lambda e: dg.depth_image(e.image, "p"),
    "prepare_depth(invalid='x')": lambda e: dg.prepare_depth(dg.depth_image(e.image, e.rig.cameras["p"]),
                                                             e.rig.cameras["p"], "x"),
    "prepare_depth(hole_pixels=-5)": lambda e: dg.prepare_depth(dg.depth_image(e.image, e.rig.cameras["p"]),
                                                                e.rig.cameras["p"], "neighbors", -5),
    "prepare_depth(array)": lambda e: dg.prepare_depth(e.image, e.rig.cameras["p"]),
    "single_camera_distances(aggregate='x')": lambda e: dg.single_camera_distances(
        dg.prepare_depth(dg.depth_image(e.image, e.rig.cameras["p"]), e.rig.cameras["p"]), e.points, 0.4, "x"),
    "single_camera_distances(occupancy=array)": lambda e: dg.single_camera_distances(e.image, e.points),
    "load_rig(None)": lambda e: dg.load_rig(None),
    "load_rig(5)": lambda e: dg.load_rig(5),
    "load_depth(None, camera)": lambda e: dg.load_depth(None, e.rig.cameras["p"]),
    "load_depth(path, None)": lambda e: dg.load_depth("depth.png", None),
    "rig_from_dict('x')": lambda e: dg.rig_from_dict("x"),
    "rig_from_dict({'cameras': 'abc'})": lambda e: dg.rig_from_dict({"cameras": "abc"}),
    "rig_from_dict(cameras=[{name: 5}])": lambda e: dg.rig_from_dict({"cameras": [{"name": 5}]}),
    "Rig({'p': 5})": lambda e: dg.Rig({"p": 5}),
    "PinholeCamera(width='64')": lambda e: dg.PinholeCamera("x", "64", 48, 50.0, 50.0, 31.5, 23.5, np.eye(4)),
    "PinholeCamera(T=None)": lambda e: dg.PinholeCamera("x", 64, 48, 50.0, 50.0, 31.5, 23.5, None),
    "PinholeCamera(noise='none')": lambda e: dg.PinholeCamera("x", 64, 48, 50.0, 50.0, 31.5, 23.5, np.eye(4),
                                                              noise="none"),
    "NoiseModel(a=nan)": lambda e: dg.NoiseModel(a=math.nan),
    "NoiseModel(k=-1)": lambda e: dg.NoiseModel(k=-1.0),
}


def _attempt(kind: str, name: str):
    e = env()
    result = call(kind, lambda: CASES[name](e), tag=name)
    if isinstance(result, Refused):
        record(kind, result.label)
        return
    violation(kind, f"{name}: accepted", f"returned {result!r:.300}")


@pytest.mark.parametrize("name", list(CASES))
def test_api_table(name):
    try:
        _attempt("api: table", name)
    except SurveyedViolation:
        pass


@campaign(60)
@given(name=st.sampled_from(list(CASES)))
@surveyed
def test_api_strategy(name):
    _attempt("api: drawn", name)
