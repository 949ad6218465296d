"""Capsules inside a link: the robot's own volume that no person can occupy (design §8a's Robot_k).

The free-space memory takes the robot's volume at each frame's joints as free. That volume must lie inside the link,
never in its padded geometry: a hand may lie on the link inside its capsule. So for each link, on the axis of its
fitted (enclosing) capsule, a capsule is found that lies inside the link's collision mesh:

1. The mesh is closed: its vertices merged, and each loop of boundary edges (a URDF mesh is often open where the
   next link attaches) fanned from the loop's centroid. Any surface spanning a hole closes it; the link's body with
   its openings so closed is what counts as inside (no finger fits in a joint's flange either way). A mesh that the
   fans do not close (a boundary edge left) gets no inner capsule.
2. Samples every ``step`` metres along the axis segment: a sample is inside when rays in three directions each cross
   the closed mesh an odd number of times (all three agree, else it is not inside), and then the ball of its
   distance d_i to the nearest triangle lies inside the mesh.
3. Each inside sample's ball of radius d_i lies inside, and so does the capsule between two neighbouring inside
   samples with radius min(d_i, d_i+1) - spacing / 2 (every point of it is within that radius of a point of the
   segment, which is within spacing / 2 of one of the two samples, so within d_i of sample i). Their union is the
   link's inner volume.

Exact up to floating point for a mesh whose triangles bound the link; it is computed once per model (well under a
second for the iiwa), in the link frame.
"""

from __future__ import annotations

import math

import numpy as np
import trimesh

from depthguard.robots._capsules import LinkCapsule

#: Metres by which every inner ball stays off the mesh.
_CLEARANCE = 1e-3

#: Three ray directions for the inside test (irrational-looking, so that no ray runs along an edge of a regular mesh).
_RAYS = np.array([[0.5773, 0.5774, 0.5775], [-0.8017, 0.2673, 0.5345], [0.1231, -0.9847, 0.1231]])
_RAYS = _RAYS / np.linalg.norm(_RAYS, axis=1)[:, None]


def inner_capsules(mesh: trimesh.Trimesh, capsule: LinkCapsule, step: float) -> list[LinkCapsule]:
    """Capsules inside ``mesh`` (link frame, metres) along the axis of ``capsule`` (the link's enclosing capsule,
    same frame), sampled every ``step`` metres at most: for each sample inside the closed mesh, the ball of its
    distance to the mesh less 1 mm, and for each two neighbouring samples inside it, the capsule between them whose
    radius is the smaller of their distances less half their spacing (when positive). Their union lies inside the
    mesh (see the module docstring); empty when no sample is inside. Each has ``padding`` 0."""
    triangles = closed_triangles(mesh)
    if triangles is None:
        return []
    count = max(int(math.ceil(capsule.length / step)) + 1, 2) if capsule.length > 0.0 else 1
    t = np.linspace(0.0, 1.0, count)
    samples = capsule.p0 + t[:, None] * (capsule.p1 - capsule.p0)
    spacing = capsule.length / (count - 1) if count > 1 else 0.0
    # Each ball 1 mm inside the mesh rather than touching it: the inner volume stays off the link's surface.
    depth = np.where(points_inside(samples, triangles), triangle_distances(samples, triangles) - _CLEARANCE, 0.0)
    out = []
    for i in range(count):
        if depth[i] > 0.0:
            out.append(LinkCapsule(link=capsule.link, p0=samples[i], p1=samples[i], radius=float(depth[i]),
                                   padding=0.0))
        if i + 1 < count and min(depth[i], depth[i + 1]) - 0.5 * spacing > 0.0:
            out.append(LinkCapsule(link=capsule.link, p0=samples[i], p1=samples[i + 1],
                                   radius=float(min(depth[i], depth[i + 1]) - 0.5 * spacing), padding=0.0))
    return out


def closed_triangles(mesh: trimesh.Trimesh) -> np.ndarray | None:
    """(m, 3, 3) float64: the mesh's triangles with each loop of boundary edges fanned from its centroid; None when
    a boundary edge is left (the fans did not close it)."""
    merged = trimesh.Trimesh(np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces), process=True)
    vertices = np.asarray(merged.vertices)
    faces = np.asarray(merged.faces)
    boundary = merged.edges_sorted[trimesh.grouping.group_rows(merged.edges_sorted, require_count=1)]
    fans = []
    for loop in _loops(boundary):
        centre = vertices[loop].mean(axis=0)
        for i in range(len(loop)):
            fans.append([centre, vertices[loop[i]], vertices[loop[(i + 1) % len(loop)]]])
    triangles = vertices[faces]
    if fans:
        triangles = np.concatenate([triangles, np.array(fans)])
        closed = trimesh.Trimesh(triangles.reshape(-1, 3), np.arange(3 * len(triangles)).reshape(-1, 3),
                                 process=True)
        if len(trimesh.grouping.group_rows(closed.edges_sorted, require_count=1)):
            return None
    return triangles


def _loops(edges: np.ndarray) -> list[list[int]]:
    """Chain (k, 2) boundary edges (vertex indices) into closed loops of vertex indices; an edge that no closed loop
    takes up is left out (the caller then finds the mesh still open)."""
    neighbours: dict[int, list[int]] = {}
    for a, b in edges:
        neighbours.setdefault(int(a), []).append(int(b))
        neighbours.setdefault(int(b), []).append(int(a))
    used = set()
    loops = []
    for a, b in edges:
        edge = (min(a, b), max(a, b))
        if edge in used:
            continue
        start, previous, current = int(a), int(a), int(b)
        loop = [start]
        path = {edge}
        while current != start:
            loop.append(current)
            following = [n for n in neighbours[current] if (min(current, n), max(current, n)) not in path
                         and (min(current, n), max(current, n)) not in used]
            if not following:
                break
            previous, current = current, following[0]
            path.add((min(previous, current), max(previous, current)))
        if current == start:
            used |= path
            loops.append(loop)
    return loops


def points_inside(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(n,) bool: whether each of the (n, 3) points lies inside the closed surface of (m, 3, 3) triangles: an odd
    number of crossings along each of three rays (all three must agree)."""
    votes = np.stack([_crossings(points, triangles, ray) % 2 == 1 for ray in _RAYS])
    return votes.all(axis=0)


def _crossings(points: np.ndarray, triangles: np.ndarray, direction: np.ndarray) -> np.ndarray:
    """(n,) int: how many of the triangles the ray from each point along ``direction`` crosses (Moeller-Trumbore)."""
    v0, v1, v2 = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    e1, e2 = v1 - v0, v2 - v0
    p = np.cross(direction, e2)
    det = np.einsum("ij,ij->i", e1, p)
    ok = np.abs(det) > 1e-15
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    out = np.zeros(len(points), dtype=np.int64)
    for i, point in enumerate(points):
        s = point - v0
        u = np.einsum("ij,ij->i", s, p) * inv
        q = np.cross(s, e1)
        v = (q @ direction) * inv
        t = np.einsum("ij,ij->i", e2, q) * inv
        out[i] = int(np.count_nonzero(ok & (u >= 0.0) & (v >= 0.0) & (u + v <= 1.0) & (t > 0.0)))
    return out


def triangle_distances(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """(n,) float64 metres: each of the (n, 3) points' distance to the nearest of the (m, 3, 3) triangles (Ericson's
    closest point on a triangle, vectorised over the triangles)."""
    a, b, c = triangles[:, 0], triangles[:, 1], triangles[:, 2]
    ab, ac = b - a, c - a
    out = np.empty(len(points))
    for i, point in enumerate(points):
        out[i] = np.sqrt(np.min(np.sum((_closest(point, a, b, c, ab, ac) - point) ** 2, axis=1)))
    return out


def _closest(p, a, b, c, ab, ac) -> np.ndarray:
    """(m, 3): the point of each triangle (a, b, c: (m, 3) each; ab = b - a, ac = c - a) nearest to p (3,)."""
    def dot(x, y):
        return np.einsum("ij,ij->i", x, y)

    ap = p - a
    d1, d2 = dot(ab, ap), dot(ac, ap)
    bp = p - b
    d3, d4 = dot(ab, bp), dot(ac, bp)
    cp = p - c
    d5, d6 = dot(ab, cp), dot(ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = 1.0 / (va + vb + vc)
        v = vb * denom
        w = vc * denom
        out = a + ab * v[:, None] + ac * w[:, None]  # inside the face
        # Edge regions (checked after the face, so that they override it), then the vertices.
        t_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        edge_bc = (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0)
        out = np.where(edge_bc[:, None], b + t_bc[:, None] * (c - b), out)
        t_ac = d2 / (d2 - d6)
        edge_ac = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
        out = np.where(edge_ac[:, None], a + t_ac[:, None] * ac, out)
        t_ab = d1 / (d1 - d3)
        edge_ab = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
        out = np.where(edge_ab[:, None], a + t_ab[:, None] * ab, out)
    out = np.where(((d6 >= 0) & (d5 <= d6))[:, None], c, out)
    out = np.where(((d3 >= 0) & (d4 <= d3))[:, None], b, out)
    out = np.where(((d1 <= 0) & (d2 <= 0))[:, None], a, out)
    # A degenerate triangle (no area) leaves NaN: its nearest vertex instead (its edges belong to its neighbours).
    bad = np.isnan(out).any(axis=1)
    if bad.any():
        corners = np.stack([a[bad], b[bad], c[bad]], axis=1)
        nearest = np.argmin(np.sum((corners - p) ** 2, axis=2), axis=1)
        out[bad] = corners[np.arange(len(corners)), nearest]
    return out
