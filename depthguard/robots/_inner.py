"""Balls inside a link: the robot's own volume that no person can occupy (design §8a's Robot_k).

The free-space memory and SSM's detectable space take the robot's volume at each frame's joints as free. That volume
must lie inside the link, never in its padded geometry: a hand may lie on the link inside its capsule. So for each
link a set of balls is found that lies inside the link's collision mesh (:func:`inner_balls`):

1. The mesh is closed: its vertices merged, and each loop of boundary edges (a URDF mesh is often open where the
   next link attaches) fanned from the loop's centroid. Any surface spanning a hole closes it; the link's body with
   its openings so closed is what counts as inside (no finger fits in a joint's flange either way). A mesh that the
   fans do not close (a boundary edge left) gets no ball.
2. A grid of candidate centres over the mesh's bounds; each one's distance to the surface bounded from below by
   samples of the surface, and inside or outside decided group by group (grid points joined where the segment between
   them cannot meet the surface), by a three-ray parity test of one point of each group.
3. The ball round an inside centre with radius that bound less 1 mm lies inside the mesh; greedily, the balls that
   hold the most grid points deep enough for a 1 cm voxel round them to lie wholly in one ball.

Sound for a mesh whose triangles bound the link; a mesh with faces inside its body (the iiwa's flange) gets smaller
balls, never larger. Computed once per model (a few seconds for the iiwa), in the link frame. Until 2026-11-29 the
inner volume was capsules along each link's enclosing capsule's axis; that axis runs along the edge of the iiwa's
links where they bend round a joint, and those capsules held a 1 cm voxel round 7-57 % of a link's points deep enough
for one, these balls 44-73 % (the flange aside; ``benchmarks/probe_robot_inside.py``).
"""

from __future__ import annotations

import math

import numpy as np
import trimesh

from depthguard import config
from depthguard.robots._capsules import LinkCapsule

#: Metres by which every inner ball stays off the mesh.
_CLEARANCE = 1e-3

#: Metres: the half-diagonal of the voxel a ball of :func:`inner_balls` is chosen to hold wholly.
_COVER = 0.5 * math.sqrt(3.0) * config.INNER_BALL_COVER_VOXEL
#: Metres: the deepest a ball of :func:`inner_balls` is searched for (a lower bound beyond; more for a link whose grid
#: or samples had to be coarsened).
_DEEPEST = 0.1
#: Metres: the balls of :func:`inner_balls` shallower than this get the fine samples' bound.
_REFINED = 0.03

#: Three ray directions for the inside test (irrational-looking, so that no ray runs along an edge of a regular mesh).
_RAYS = np.array([[0.5773, 0.5774, 0.5775], [-0.8017, 0.2673, 0.5345], [0.1231, -0.9847, 0.1231]])
_RAYS = _RAYS / np.linalg.norm(_RAYS, axis=1)[:, None]


def inner_balls(mesh: trimesh.Trimesh, link: str, spacing: float = config.INNER_BALL_SPACING,
                count: int = config.INNER_BALLS, cover: float = _COVER,
                sample: float = config.INNER_SURFACE_SAMPLE) -> list[LinkCapsule]:
    """Balls inside ``mesh`` (link frame, metres; open ends closed as :func:`closed_triangles` closes them), chosen to
    fill it: each a sample of a grid ``spacing`` metres a side with the ball of its distance to the mesh (a lower
    bound: less ``sample`` and 1 mm), at most ``count`` of them, picked greedily so that as many grid points as
    possible lie at least ``cover`` metres deep in one ball (the half-diagonal of the voxels that must fit wholly in
    one: ``robot_inside_voxels``; where no grid point lies that deep, the grid is halved while it stays coarser than
    4 ``sample``). Each a :class:`LinkCapsule` with p0 = p1 and ``padding`` 0; empty when the mesh is not closed.

    Sound for a closed mesh, by three steps each of which only errs towards "not inside":
    1. Distance: every triangle is cut into equal pieces whose edges are at most ``sample`` metres, so every point
       of the surface lies within ``sample`` of a piece's corner; a grid point's distance to the nearest corner less
       ``sample`` is at most its distance to the surface.
    2. Inside: grid points whose lower bound exceeds spacing / 2 are joined to their six neighbours (the segment
       between two such points cannot meet the surface: each of its points is within spacing / 2 of one end). A
       group that reaches the grid's rim (which lies outside the mesh's bounds) is outside; every other group is
       inside or outside as a whole, decided by the three-ray parity test of one of its points (all three agree).
    3. The ball round an inside point with radius its lower bound less 1 mm lies inside the mesh.

    Bounded work for any mesh a URDF may bring (up to ``config.COORDINATE_LIMIT`` across): the grid, the surface
    samples and the pairs the greedy choice weighs are each held under ``config.INNER_BALL_LIMITS``' counts by a
    coarser grid, coarser samples (whose spacing the bound then subtracts) or every k-th grid point counted, which
    change how well the balls fill the link, never whether they lie inside it."""
    from scipy import sparse
    from scipy.spatial import cKDTree

    if count < 1:
        return []
    triangles = closed_triangles(mesh)
    if triangles is None:
        return []
    centres, radii = _inside_samples(triangles, spacing, sample)
    targets = centres[radii + _CLEARANCE >= cover]  # points that lie at least ``cover`` deep in the mesh
    if not len(targets):  # a thin link (a flange) the grid's points miss the middle of: a grid half as fine
        return inner_balls(mesh, link, 0.5 * spacing, count, cover, sample) if spacing > 4.0 * sample else []
    useful = np.flatnonzero(radii > cover)
    tree = cKDTree(targets)
    pairs = int(tree.query_ball_point(centres[useful], radii[useful] - cover, return_length=True).sum())
    most = config.INNER_BALL_LIMITS["pairs"]
    if pairs > most:  # the greedy choice weighs every k-th target only
        targets = targets[::-(-pairs // most)]
        tree = cKDTree(targets)
    reached = tree.query_ball_point(centres[useful], radii[useful] - cover)
    rows = np.repeat(useful, [len(r) for r in reached])
    cols = np.concatenate([np.asarray(r, dtype=np.int64) for r in reached]) if len(useful) else rows
    covers = sparse.csr_matrix((np.ones(len(rows)), (rows, cols)), shape=(len(centres), len(targets)))
    uncovered = np.ones(len(targets))
    out = []
    for _ in range(count):
        gains = covers @ uncovered
        best = int(np.argmax(gains))
        if gains[best] <= 0.0:
            break
        uncovered[covers[best].indices] = 0.0
        out.append(LinkCapsule(link=link, p0=centres[best].copy(), p1=centres[best].copy(),
                               radius=float(radii[best]), padding=0.0))
    return out


def _inside_samples(triangles: np.ndarray, spacing: float, sample: float) -> tuple[np.ndarray, np.ndarray]:
    """((k, 3) centres, (k,) radii), metres: the points of a grid ``spacing`` a side inside the closed surface of
    (m, 3, 3) ``triangles``, each with a lower bound of its distance to it less 1 mm (> 0): steps 1-3 of
    :func:`inner_balls`."""
    from scipy import ndimage
    from scipy.spatial import cKDTree

    extent = np.ptp(triangles.reshape(-1, 3), axis=0)
    while np.prod(np.floor(extent / spacing) + 4.0) > config.INNER_BALL_LIMITS["grid"]:
        spacing *= 2.0
    lo = triangles.reshape(-1, 3).min(axis=0) - spacing
    hi = triangles.reshape(-1, 3).max(axis=0) + spacing
    axes = [np.arange(lo[a], hi[a] + spacing, spacing) for a in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)
    # Coarse samples for the grouping, the fine ones for the depths of the shallow points inside (a KD query costs
    # with the samples' density and the distance it searches). The grouping needs only whether a point is deeper
    # than spacing / 2, so its queries stop at spacing plus the samples' slack; the depths' queries stop at 10 cm
    # (no link is thicker than 20 cm). A query that stops at a bound returns inf: the bound is then a lower bound of
    # the distance.
    sample = _sample_spacing(triangles, sample)
    coarse = _sample_spacing(triangles, 2.0 * sample)
    tree = cKDTree(_surface_samples(triangles, coarse))
    enough = spacing + coarse
    reach = tree.query(grid.reshape(-1, 3), distance_upper_bound=enough, workers=-1)[0]
    depth = np.minimum(reach, enough).reshape(grid.shape[:3]) - coarse
    groups, n_groups = ndimage.label(depth > 0.5 * spacing)  # six-connected
    rim = np.unique(np.concatenate([groups[0].ravel(), groups[-1].ravel(), groups[:, 0].ravel(),
                                    groups[:, -1].ravel(), groups[:, :, 0].ravel(), groups[:, :, -1].ravel()]))
    inside = np.zeros(n_groups + 1, dtype=bool)
    labels, first = np.unique(groups.ravel(), return_index=True)  # one point of each group
    enclosed = (labels > 0) & ~np.isin(labels, rim)
    if enclosed.any():
        inside[labels[enclosed]] = points_inside(grid.reshape(-1, 3)[first[enclosed]], triangles)
    mask = inside[groups]
    centres = grid[mask]
    deepest = max(_DEEPEST, 2.0 * spacing, 4.0 * coarse)  # a link so large its grid or samples were coarsened
    reach = tree.query(centres, distance_upper_bound=deepest, workers=-1)[0]
    radii = np.minimum(reach, deepest) - coarse - _CLEARANCE
    shallow = radii < _REFINED  # the fine samples where the bound's slack weighs most (and the query is quick)
    reach = cKDTree(_surface_samples(triangles, sample)).query(centres[shallow], distance_upper_bound=deepest,
                                                               workers=-1)[0]
    radii[shallow] = np.minimum(reach, deepest) - sample - _CLEARANCE
    keep = radii > 0.0
    return centres[keep], radii[keep]


def _sample_spacing(triangles: np.ndarray, sample: float) -> float:
    """``sample`` metres, doubled until :func:`_surface_samples` gives at most ``config.INNER_BALL_LIMITS['samples']``
    corners."""
    edges = _longest_edges(triangles)
    while True:
        n = np.maximum(np.ceil(edges / sample), 1.0)
        if np.sum((n + 1.0) * (n + 2.0) / 2.0) <= config.INNER_BALL_LIMITS["samples"]:
            return sample
        sample *= 2.0


def _longest_edges(triangles: np.ndarray) -> np.ndarray:
    """(m,) metres: each of the (m, 3, 3) triangles' longest edge."""
    return np.stack([np.linalg.norm(triangles[:, 1] - triangles[:, 0], axis=1),
                     np.linalg.norm(triangles[:, 2] - triangles[:, 1], axis=1),
                     np.linalg.norm(triangles[:, 0] - triangles[:, 2], axis=1)], axis=1).max(axis=1)


def _surface_samples(triangles: np.ndarray, sample: float) -> np.ndarray:
    """(k, 3): the corners of every triangle of (m, 3, 3) cut into n^2 equal pieces, n the smallest with every
    piece's edges at most ``sample`` metres: every point of a piece lies within its longest edge of each corner."""
    out = []
    pieces = np.maximum(np.ceil(_longest_edges(triangles) / sample), 1).astype(np.int64)
    for n in np.unique(pieces):
        group = triangles[pieces == n]
        i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
        keep = i + j <= n
        u, v = (i[keep] / n)[:, None], (j[keep] / n)[:, None]
        a, b, c = group[:, None, 0], group[:, None, 1], group[:, None, 2]
        out.append((a + u * (b - a) + v * (c - a)).reshape(-1, 3))
    return np.concatenate(out)


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
