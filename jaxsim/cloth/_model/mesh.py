"""Cloth from a triangle mesh: springs on the edges, bending springs across them, lumped masses."""

from __future__ import annotations

import numpy as np

from ..._dtype import check_float_dtype, default_float
from ..._validate import check_finite, check_int, check_real, check_shape
from .scene import Cloth, pin_mask


def check_triangles(vertices, triangles) -> tuple[np.ndarray, np.ndarray]:
    """``(vertices (N, 3) float64, triangles (F, 3) int64)`` after the mesh checks
    (``ValueError`` on bad shapes, ids out of range, or zero-area triangles)."""
    V = check_finite("vertices", check_shape("vertices", vertices, (None, 3))).astype(np.float64)
    T = np.asarray(triangles)
    if T.size == 0:
        raise ValueError("a mesh needs at least one triangle")
    T = check_shape("triangles", T, (None, 3))
    if not np.issubdtype(T.dtype, np.integer):
        raise ValueError(f"triangles must hold integer vertex ids, got dtype {T.dtype}")
    N = len(V)
    if T.min() < 0 or T.max() >= N:
        raise ValueError(f"triangle vertex ids must lie in [0, {N}), got range [{T.min()}, {T.max()}]")
    area = triangle_areas(V, T)
    scale = max(float(np.ptp(V, axis=0).max()), np.finfo(np.float64).tiny)
    bad = np.flatnonzero(~(area > 1e-12 * scale * scale))
    if bad.size:
        raise ValueError(f"{bad.size} degenerate (zero-area) triangles, first ids {bad[:5].tolist()}")
    return V, T.astype(np.int64)


def triangle_areas(V, T) -> np.ndarray:
    """``(F,)`` triangle areas (m^2)."""
    return 0.5 * np.linalg.norm(np.cross(V[T[:, 1]] - V[T[:, 0]], V[T[:, 2]] - V[T[:, 0]]), axis=-1)


def mesh_springs(triangles, n_vertices: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Structural and bending springs of a manifold triangle mesh.

    Returns:
      ``(edges (E, 2), bending (B, 2))`` int32, each pair sorted and each list sorted:
      the unique triangle edges, and for every interior edge (shared by two triangles)
      the pair of vertices opposite it.

    Raises:
      ValueError: an edge shared by more than two triangles (non-manifold), or two
        triangles on the same three vertices.
    """
    T = np.asarray(triangles, np.int64).reshape(-1, 3)
    e = np.concatenate([T[:, [0, 1]], T[:, [1, 2]], T[:, [2, 0]]])
    opposite = np.concatenate([T[:, 2], T[:, 0], T[:, 1]])
    e.sort(axis=1)
    edges, inverse, counts = np.unique(e, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.reshape(-1)
    if counts.max() > 2:
        bad = edges[counts > 2]
        raise ValueError(f"{len(bad)} non-manifold edges (shared by more than two triangles), first "
                         f"{bad[0].tolist()}; split the mesh there")
    order = np.argsort(inverse, kind="stable")
    inv_sorted, opp_sorted = inverse[order], opposite[order]
    first = np.flatnonzero(np.r_[True, inv_sorted[1:] != inv_sorted[:-1]])
    pairs = first[counts[inv_sorted[first]] == 2]
    bend = np.stack([opp_sorted[pairs], opp_sorted[pairs + 1]], -1)
    if np.any(bend[:, 0] == bend[:, 1]):
        raise ValueError("two triangles share the same three vertices (a duplicated triangle)")
    bend.sort(axis=1)
    bend = np.unique(bend, axis=0) if len(bend) else bend.reshape(0, 2)
    return edges.astype(np.int32), bend.astype(np.int32)


def lumped_masses(V, T, density: float) -> np.ndarray:
    """``(N,)`` vertex masses (kg): a third of each adjacent triangle's area times ``density``."""
    m = np.zeros(len(V))
    np.add.at(m, T.reshape(-1), np.repeat(triangle_areas(V, T) * density / 3.0, 3))
    return m


def from_mesh(vertices, triangles, *, stiffness: float = 100.0, bending: float | None = None, density: float = 0.2,
              damping: float = 0.02, gravity: float = 9.8, pins=None, dtype=None, colliders=(),
              contact_gap=None, self_contact: bool = False, self_contact_pairs: int | None = None,
              wind=None, drag: float | None = None, lift: float | None = None) -> Cloth:
    """A cloth from a triangle mesh.

    - Structural springs on the unique triangle edges, of stiffness ``stiffness``.
    - Bending springs across every interior edge, joining the two vertices opposite it,
      of stiffness ``bending`` (default ``stiffness / 10``).
    - Masses lumped from the triangle areas times ``density``.
    - Rest lengths are the mesh's edge lengths; no pins unless ``pins`` gives ids.

    On a grid's triangulation this gives the grid's structural springs plus one
    diagonal per cell, and the bending springs across those diagonals are the cells'
    other diagonals: together the grid's structural and shear springs.  Bending across
    the axis-aligned edges joins vertices a knight's move apart, where ``grid`` uses
    skip-one springs along the rows and columns.

    Args:
      vertices: ``(N, 3)`` rest positions (m).
      triangles: ``(F, 3)`` vertex ids.
      stiffness, bending: spring constants (N/m).
      density: area density (kg/m^2).
      damping: along-spring damping (N s/m).
      gravity: magnitude (m/s^2) of the acceleration ``(0, -gravity, 0)``.
      pins: pinned vertex ids (default none).
      dtype: float32 or float64 (default: JAX's default float).
      colliders, contact_gap: as for :class:`Cloth`.
      self_contact, self_contact_pairs: as for :class:`Cloth` (the triangles are the mesh's).
      wind, drag, lift: as for :class:`Cloth` (on the mesh's triangles).

    Raises:
      ValueError: bad shapes, ids out of range, zero-area or duplicated triangles,
        non-manifold edges, vertices in no triangle, non-positive density; with
        ``self_contact``, a rest shape that intersects itself (the first crossing named).
    """
    V, T = check_triangles(vertices, triangles)
    density = check_real("density", density, minimum=0.0, strict=True)
    for name, val in (("stiffness", stiffness), ("damping", damping), ("gravity", gravity)):
        check_real(name, val)
    bending = stiffness / 10.0 if bending is None else check_real("bending", bending, minimum=0.0)
    edges, bend = mesh_springs(T)
    unused = np.setdiff1d(np.arange(len(V)), T)
    if unused.size:
        raise ValueError(f"{unused.size} vertices belong to no triangle (first ids {unused[:5].tolist()}); "
                         "they would have no mass")
    springs = np.concatenate([edges, bend])
    L = np.linalg.norm(V[springs[:, 1]] - V[springs[:, 0]], axis=-1)
    folded = np.flatnonzero(L[len(edges):] <= 1e-12 * max(float(np.ptp(V, axis=0).max()), 1e-300))
    if folded.size:
        i, j = bend[folded[0]]
        raise ValueError(f"the mesh folds flat onto itself: {folded.size} pairs of triangles across an edge have "
                         f"their opposite vertices at one point (first: vertices {i} and {j}), so the bending "
                         "spring between them would have rest length 0; unfold the rest shape")
    k = np.concatenate([np.full(len(edges), float(stiffness)), np.full(len(bend), float(bending))])
    dtype = default_float() if dtype is None else check_float_dtype("from_mesh", dtype)
    return Cloth(
        rest=V.astype(dtype), springs=springs, rest_length=L.astype(dtype), stiffness=k.astype(dtype),
        mass=lumped_masses(V, T, density).astype(dtype), pinned=pin_mask(len(V), [] if pins is None else pins),
        gravity=np.asarray([0.0, -gravity, 0.0], dtype), damping=np.asarray(damping, dtype), colliders=colliders,
        contact_gap=contact_gap, contact_faces=T if self_contact or drag or lift else None,
        self_contact=bool(self_contact), self_contact_pairs=self_contact_pairs, wind=wind, drag=drag, lift=lift,
    )


def disk(rings: int = 12, radius: float = 1.0, center=(0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """A flat disk in the plane ``y = center[1]``: ``(vertices (N, 3), triangles (F, 3))``,
    ``rings`` concentric rings with ``6 r`` vertices on ring ``r`` (near-equilateral)."""
    rings = check_int("disk rings", rings, 1)
    radius = check_real("disk radius", radius, minimum=0.0, strict=True)
    if np.shape(center) != (3,):
        raise ValueError(f"disk center must be 3 numbers, got {center!r}")
    check_finite("disk center", np.asarray(center, float))
    pts = [np.zeros(3)]
    start = [0]
    for r in range(1, rings + 1):
        start.append(len(pts))
        ang = 2 * np.pi * np.arange(6 * r) / (6 * r)
        pts += [np.array([np.cos(a), 0.0, np.sin(a)]) * radius * r / rings for a in ang]
    tris = [(0, start[1] + (k + 1) % 6, start[1] + k) for k in range(6)]
    for r in range(2, rings + 1):  # zip ring r-1 and ring r together in order of angle
        n_in, n_out = 6 * (r - 1), 6 * r
        i = o = 0
        while i < n_in or o < n_out:
            vi, vo = start[r - 1] + i % n_in, start[r] + o % n_out
            if o < n_out and (i >= n_in or (o + 1) / n_out <= (i + 1) / n_in):
                tris.append((vi, start[r] + (o + 1) % n_out, vo))
                o += 1
            else:
                tris.append((vi, start[r - 1] + (i + 1) % n_in, vo))
                i += 1
    V = np.asarray(pts) + np.asarray(center, float)
    return V, np.asarray(tris, np.int32)
