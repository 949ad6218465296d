"""Campaign (issue 12, item 8): the exact oracle on valid inputs, one camera and two fused, under random rigid
transforms of the whole setup. The geometry and the rule are in ``tests/campaign_support.py``.

**Fused layout.** The principal camera ``p`` looks straight at the wall z = D of its optical frame; the secondary
``s`` stands beside it on the same side of the wall (up to 0.3 m away, turned by up to ~8 degrees) and sees the same
wall: each of its pixels reports the nearest wall depth over its footprint, so it never claims to see beyond the
wall. The real obstacles are the wall and everything behind it (neither camera sees behind it), and the depth grid of
principal ``p`` counts p's unseen space as occupied (design §3 and §8: space outside the principal's image or
depth range, and a surveillance region leaving the grid, are occupied). So the fused free space is the same polytope
P as for ``p`` alone, and the fused answer obeys the same oracle: reported <= the distance to the complement of P,
which is the distance to the wall's occupied half-space and to the principal's unseen space.
"""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

import depthguard as dg
from campaign_support import (
    TOL,
    Refused,
    call,
    campaign,
    check_result,
    exact_distance,
    finite,
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


def _query(kind, rig, frames, points_world, **options):
    return call(kind, lambda: dg.DistanceMonitor(rig, **options).query(frames, points_world))


@campaign(60)
@given(G=rigid_transforms(), wall=walls(), data=st.data(), rho=finite(0.01, 2.0),
       aggregate=st.sampled_from(AGGREGATES))
@surveyed
def test_single_camera_never_above_the_exact_distance(G, wall, data, rho, aggregate):
    kind = "valid: single"
    image_kind, value, D = wall
    points = np.array(data.draw(point_sets(D, max_size=8)))
    result = _query(kind, single_rig(G), {"p": wall_image(value, image_kind)}, to_world(G, points), rho=rho,
                    aggregate=aggregate)
    if isinstance(result, Refused):
        violation(kind, "valid input refused", str(result.exc))
    record(kind, check_result(kind, result, points, D, rho, aggregate, context=f"wall {D} m ({image_kind})"))


@campaign(40)
@given(G=rigid_transforms(), wall=walls(hi_mm=3600), layout=secondary_layouts(), secondary_kind=st.sampled_from(
    ["f32", "u16"]), data=st.data(), rho=finite(0.01, 1.5), aggregate=st.sampled_from(AGGREGATES))
@surveyed
def test_fused_never_above_the_exact_distance(G, wall, layout, secondary_kind, data, rho, aggregate):
    kind = "valid: fused"
    image_kind, value, D = wall
    points = np.array(data.draw(point_sets(D, max_size=8)))
    frames = {"p": wall_image(value, image_kind), "s": secondary_image(layout, D, secondary_kind)}
    result = _query(kind, fused_rig(G, layout), frames, to_world(G, points), rho=rho, aggregate=aggregate)
    if isinstance(result, Refused):
        violation(kind, "valid input refused", str(result.exc))
    record(kind, check_result(kind, result, points, D, rho, aggregate, context=f"wall {D} m, layout {layout.tolist()}"))


def test_the_oracle_is_tight_for_a_clean_single_camera():
    """The oracle itself: with no noise margin and the exact method, ``min`` on a clean wall gives exactly the
    distance to the complement of P (design §4 and §6), so the oracle is the true answer, not a loose bound."""
    D = 2.0
    points = np.array([[0.0, 0.0, 1.0], [0.5, 0.2, 1.5], [0.0, 0.3, 1.8], [-0.4, -0.25, 0.5], [0.1, 0.0, 0.4],
                       [0.0, 0.0, 1.7]])
    rig = single_rig(np.eye(4))
    result = dg.DistanceMonitor(rig, rho=0.5, aggregate="min").query({"p": wall_image(D, "f32")}, points)
    exact = exact_distance(points, D)
    near = exact < 0.5
    assert near.sum() >= 4
    np.testing.assert_allclose(result.distance[near], exact[near], atol=TOL)
    assert np.all(np.isinf(result.distance[~near]))
