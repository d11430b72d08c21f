"""Drawing a cloth as a shaded triangle surface, with its colliders."""

from __future__ import annotations

import jax
import numpy as np

from ._common import check_fps, check_frames, new_figure, world_cube, world_limits
from ._gif import GifWriter, gif_dpi
from ._style import CLOTH, FLOOR, SOLID, legend

#: The cloth's faces sort this fraction of the scene's depth range nearer than they are, a
#: polygon offset: a cloth resting on a collider (a contact gap away, far less than its
#: triangles' size) is drawn over the collider faces it covers (``_depth_sorted``).
FRONT = 0.05

#: Light direction (world, y up) for the Lambert shading.
LIGHT = np.array([0.4, 1.0, 0.3]) / np.linalg.norm([0.4, 1.0, 0.3])


def _check_triangles(triangles, n):
    T = np.asarray(triangles)
    if T.ndim != 2 or T.shape[1] != 3 or not np.issubdtype(T.dtype, np.integer) or T.min() < 0 or T.max() >= n:
        raise ValueError(f"triangles must be (F, 3) integer ids in [0, {n})")
    return T


def _shade(x, T, base=CLOTH):
    """``(F, 4)`` RGBA face colours: Lambert shading, two-sided (cloth has no inside)."""
    return _lambert(_normals(x[T]), base)


def _polys(x, T):
    return x[T][..., [0, 2, 1]]  # draw (x, z, y): world y up on the plot's vertical axis


def _check_colliders(colliders, frames: int | None = None) -> tuple:
    """One static collider or a tuple of them, each with a scene's shapes; with ``frames``,
    also a path: every leaf with a leading ``(frames,)`` axis.  Returns ``(colliders,
    moving)``, or the colliders alone without ``frames``."""
    from ..cloth._model.colliders import COLLIDERS, check_scene_shapes

    if isinstance(colliders, COLLIDERS):
        colliders = (colliders,)
    if not isinstance(colliders, (tuple, list)) or not all(isinstance(c, COLLIDERS) for c in colliders):
        raise ValueError(f"colliders must be a tuple of cloth.Plane, cloth.Sphere or cloth.Capsule, got {colliders!r:.120}")
    colliders = tuple(colliders)
    leaves = jax.tree_util.tree_leaves(colliders)
    if frames is not None and colliders and all(np.ndim(a) >= 1 and np.shape(a)[0] == frames for a in leaves):
        for k, c in enumerate(colliders):
            check_scene_shapes(jax.tree_util.tree_map(lambda a: a[0], c), k, "a path has one leading frame axis")
        return colliders, True
    for k, c in enumerate(colliders):
        check_scene_shapes(c, k, "draw one scene's or one step's colliders: jax.tree_util.tree_map(lambda a: a[t], "
                                 "colliders), or pass a path with one entry per frame of xs")
    return colliders if frames is None else (colliders, False)


def _lambert(normals, base, alpha=1.0):
    """``(F, 4)`` RGBA: two-sided Lambert shading of faces with unit ``normals (F, 3)``."""
    lam = 0.35 + 0.65 * np.abs(normals @ LIGHT)
    rgb = np.clip(np.asarray(base)[None, :] * lam[:, None], 0, 1)
    return np.concatenate([rgb, np.full((len(normals), 1), alpha)], axis=1)


def _grid_faces(P):
    """Triangles ``(2 (m-1) (n-1), 3, 3)`` of a ``(m, n, 3)`` grid of points."""
    a, b, c, d = P[:-1, :-1], P[1:, :-1], P[1:, 1:], P[:-1, 1:]
    return np.concatenate([np.stack([a, b, c], -2).reshape(-1, 3, 3), np.stack([a, c, d], -2).reshape(-1, 3, 3)])


def _normals(F):
    n = np.cross(F[:, 1] - F[:, 0], F[:, 2] - F[:, 0])
    return n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)


def _collider_faces(colliders, center, radius):
    """``(faces (F, 3, 3) world, rgba (F, 4))`` of every collider: spheres and capsules as
    shaded solids, planes as a tiled translucent square around ``center`` (half-width
    ``radius``).  They are drawn in one collection with the cloth's triangles, so
    matplotlib's depth sort orders all faces together (a painter's algorithm, with the
    cloth's faces offset toward the camera: ``FRONT``)."""
    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, 25), np.linspace(0, np.pi, 13))
    ball = np.stack([np.cos(u) * np.sin(v), np.cos(v), np.sin(u) * np.sin(v)], -1)
    faces, colors = [], []
    for c in colliders:
        kind = type(c).__name__
        parts = []
        if kind == "Sphere":
            parts.append(_grid_faces(np.asarray(c.center) + float(c.radius) * ball))
        elif kind == "Capsule":
            a, b, r = np.asarray(c.a), np.asarray(c.b), float(c.radius)
            parts += [_grid_faces(a + r * ball), _grid_faces(b + r * ball)]
            axis = b - a
            n = axis / max(np.linalg.norm(axis), 1e-12)
            e1 = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 0.0, 1.0])
            e1 /= np.linalg.norm(e1)
            e2 = np.cross(n, e1)
            th = np.linspace(0, 2 * np.pi, 25)
            ring = r * (np.cos(th)[:, None] * e1 + np.sin(th)[:, None] * e2)
            k = np.linspace(0.0, 1.0, max(2, int(np.ceil(np.linalg.norm(axis) / r)) + 1))  # faces about r long,
            parts.append(_grid_faces(a + k[None, :, None] * axis + ring[:, None, :]))  # for the depth sort
        if parts:
            F = np.concatenate(parts)
            faces.append(F)
            colors.append(_lambert(_normals(F), SOLID))
        elif kind == "Plane":
            n, o = np.asarray(c.normal), float(c.offset)
            a = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 0.0, 1.0])
            a /= np.linalg.norm(a)
            b = np.cross(n, a)
            p0 = center - (center @ n - o) * n
            t = np.linspace(-radius, radius, 9)
            A, B = np.meshgrid(t, t, indexing="ij")
            F = _grid_faces(p0 + A[..., None] * a + B[..., None] * b)
            faces.append(F)
            colors.append(_lambert(_normals(F), FLOOR, alpha=0.55))
    if not faces:
        return np.zeros((0, 3, 3)), np.zeros((0, 4))
    return np.concatenate(faces), np.concatenate(colors)


def _floor(colliders):
    """The height of the highest horizontal plane collider (normal +y), or ``None``."""
    ys = [float(c.offset) / float(np.asarray(c.normal)[1]) for c in colliders if type(c).__name__ == "Plane"
          and abs(float(np.asarray(c.normal)[1])) > 0.999]
    return max(ys) if ys else None


def _depth_sorted(polys, rgba, n_cloth: int):
    """One ``Poly3DCollection`` of ``polys`` whose first ``n_cloth`` faces (the cloth) sort
    ``FRONT`` of the depth range nearer than their centroids (where matplotlib lets the
    sort be set; otherwise its plain centroid sort)."""
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    out = Poly3DCollection(polys, facecolors=rgba, linewidths=0, zsort="average")

    def zsort(pzs, axis=-1):
        z = np.array(np.average(pzs, axis=axis))
        if z.size:
            z[:n_cloth] -= FRONT * float(np.ptp(z))  # larger is farther: drawn first
        return z

    if hasattr(out, "_zsortfunc"):
        out._zsortfunc = zsort
    return out


def _scene(x, T, colliders_faces):
    """``(polys, rgba)`` of the cloth at ``x`` and the collider faces, in drawing order
    ``(x, z, y)``, for one ``Poly3DCollection``."""
    F, rgba = colliders_faces
    return np.concatenate([_polys(x, T), F[..., [0, 2, 1]]]), np.concatenate([_shade(x, T), rgba])


def plot_surface(x, triangles, colliders=(), ax=None, title: str = ""):
    """Draw the mesh ``triangles (F, 3)`` at positions ``x (N, 3)``, shaded, with the
    colliders.  Returns the figure."""
    x = np.asarray(x, np.float64)
    if x.ndim != 2 or x.shape[1] != 3:
        raise ValueError(f"x must have shape (N, 3), got {x.shape}")
    if not np.all(np.isfinite(x)):
        raise ValueError(f"x has {int(np.sum(~np.all(np.isfinite(x), axis=1)))} particles with NaN or infinite "
                         "positions; nothing sensible can be drawn")
    T = _check_triangles(triangles, len(x))
    colliders = _check_colliders(colliders)
    if ax is None:
        fig, ax = new_figure(4.5, 4.5, projection="3d")
    c, r = world_limits(ax, x, _floor(colliders))
    polys, rgba = _scene(x, T, _collider_faces(colliders, c, r))
    ax.add_collection3d(_depth_sorted(polys, rgba, len(T)))
    _legend(ax, colliders)
    ax.set_title(title)
    return ax.figure


def _legend(ax, colliders):
    """Patches for the cloth and each kind of collider drawn."""
    from matplotlib.patches import Patch

    kinds = dict.fromkeys(type(c).__name__ for c in colliders)
    handles = [Patch(color=CLOTH, label="cloth")] + [
        Patch(color=FLOOR if k == "Plane" else SOLID, label={"Plane": "floor (plane)"}.get(k, k.lower()))
        for k in kinds]
    legend(ax, handles=handles)


def animate_surface(xs, triangles, path: str, colliders=(), fps: int = 30, stride: int = 1, title: str = "",
                    dpi: float | None = None, elev: float = 20.0, azim: float = -60.0, follow: bool = False):
    """Write a GIF of the shaded mesh over ``xs (T, N, 3)``, with the colliders depth-sorted
    together with it, and a legend.  ``colliders``: static, or a path with a leading
    ``(T,)`` axis on every leaf (one pose per frame of ``xs``: moving capsules of a body).

    ``dpi``: default the least that gives a short side of 480 px (``_gif``); ``elev`` and
    ``azim``: the camera (degrees, matplotlib's); ``follow``: the view box moves with the
    cloth (its size stays that of the largest frame).  Returns the frame count.
    """
    fps = check_fps(fps)
    xs = np.asarray(xs, np.float64)
    xs = check_frames("xs", xs, (xs.shape[-2] if xs.ndim == 3 else -1, 3))
    T = _check_triangles(triangles, xs.shape[1])
    colliders, moving = _check_colliders(colliders, len(xs))
    at = (lambda t: tuple(jax.tree_util.tree_map(lambda a: np.asarray(a)[t], colliders))) if moving else (
        lambda t: colliders)
    fig, ax = new_figure(4, 4, projection="3d")
    dpi = gif_dpi(fig, dpi)
    ax.view_init(elev=elev, azim=azim)
    extent = xs.reshape(-1, 3)
    if moving:  # the body's path in view too
        ends = [np.asarray(getattr(c, f)).reshape(-1, 3) for c in colliders for f in ("a", "b", "center")
                if hasattr(c, f)]
        extent = np.concatenate([extent] + ends)
    c, r = world_limits(ax, extent, _floor(at(0)))
    if follow:  # a box the size of the largest frame's, centred on each frame's cloth
        r = 0.55 * max(float(np.max(np.ptp(xs, axis=1))), 1e-3) * 1.6
        centres = 0.5 * (xs.min(1) + xs.max(1))
        c = centres[0]
        world_cube(ax, c, r)
    solids = _collider_faces(at(0), c, r)
    polys, rgba = _scene(xs[0], T, solids)
    surf = _depth_sorted(polys, rgba, len(T))
    ax.add_collection3d(surf)
    _legend(ax, at(0))
    txt = ax.set_title(title, fontsize=9)
    frames = range(0, len(xs), max(1, int(stride)))
    with GifWriter(fig, path, fps, dpi) as writer:
        for t in frames:
            if follow:
                c = centres[t]
                world_cube(ax, c, r)
            if moving:
                solids = _collider_faces(at(t), c, r)
            polys, rgba = _scene(xs[t], T, solids)
            surf.set_verts(polys)
            surf.set_facecolor(rgba)
            txt.set_text(f"{title}  step {t + 1}" if title else f"step {t + 1}")
            writer.grab()
    return len(frames)
