"""A simple standing person made of capsules and a sphere, for synthetic scenes and benchmarks."""

from __future__ import annotations

import numpy as np

from depthguard.scenes import Capsule, Sphere


def standing_person(position, height: float = 1.75, facing: float = 0.0, reach: float = 0.0) -> list:
    """A standing person as solid primitives: legs, torso, head, arms (capsules and a sphere).

    Args:
        position: (x, y) metres, world frame: the point between the feet (the floor is z = 0, z points up).
        height: metres.
        facing: heading angle (radians) of the direction the person faces, about +z from +x.
        reach: 0 (arms down) to 1 (right arm stretched forward at shoulder height).
    """
    x, y = float(position[0]), float(position[1])
    s = height / 1.75
    forward = np.array([np.cos(facing), np.sin(facing), 0.0])
    side = np.array([-np.sin(facing), np.cos(facing), 0.0])  # the person's left
    base = np.array([x, y, 0.0])
    hip = base + [0, 0, 0.9 * s]
    shoulder_height = 1.42 * s
    parts = [
        Capsule(tuple(base + 0.1 * s * side + [0, 0, 0.08 * s]), tuple(hip + 0.1 * s * side), 0.08 * s),
        Capsule(tuple(base - 0.1 * s * side + [0, 0, 0.08 * s]), tuple(hip - 0.1 * s * side), 0.08 * s),
        Capsule(tuple(hip + [0, 0, 0.05 * s]), tuple(base + [0, 0, shoulder_height - 0.08 * s]), 0.17 * s),
        Sphere(tuple(base + [0, 0, 1.62 * s]), 0.11 * s),
    ]
    left_shoulder = base + [0, 0, shoulder_height] + 0.22 * s * side
    right_shoulder = base + [0, 0, shoulder_height] - 0.22 * s * side
    parts.append(Capsule(tuple(left_shoulder), tuple(left_shoulder + [0, 0, -0.6 * s]), 0.05 * s))
    down = np.array([0, 0, -0.6 * s])
    ahead = 0.65 * s * forward
    hand = right_shoulder + (1 - reach) * down + reach * ahead
    parts.append(Capsule(tuple(right_shoulder), tuple(hand), 0.05 * s))
    return parts
