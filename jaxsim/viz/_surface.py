"""Drawing a cloth as a shaded triangle surface, with its colliders."""

from __future__ import annotations

import numpy as np

from ._common import check_fps, check_frames, new_figure, world_limits

#: Light direction (world, y up) for the Lambert shading.
LIGHT = np.array([0.4, 1.0, 0.3]) / np.linalg.norm([0.4, 1.0, 0.3])


def _check_triangles(triangles, n):
    T = np.asarray(triangles)
    if T.ndim != 2 or T.shape[1] != 3 or not np.issubdtype(T.dtype, np.integer) or T.min() < 0 or T.max() >= n:
        raise ValueError(f"triangles must be (F, 3) integer ids in [0, {n})")
    return T


def _shade(x, T, base=(0.25, 0.45, 0.85)):
    """``(F, 4)`` RGBA face colours: Lambert shading, two-sided (cloth has no inside)."""
    n = np.cross(x[T[:, 1]] - x[T[:, 0]], x[T[:, 2]] - x[T[:, 0]])
    n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12)
    lam = 0.35 + 0.65 * np.abs(n @ LIGHT)
    rgb = np.clip(np.asarray(base)[None, :] * lam[:, None], 0, 1)
    return np.concatenate([rgb, np.ones((len(T), 1))], axis=1)


def _polys(x, T):
    return x[T][..., [0, 2, 1]]  # draw (x, z, y): world y up on the plot's vertical axis


def _check_colliders(colliders) -> tuple:
    """One static collider or a tuple of them, each with a scene's shapes (no path axis)."""
    from ..cloth._model.colliders import COLLIDERS, check_scene_shapes

    if isinstance(colliders, COLLIDERS):
        colliders = (colliders,)
    if not isinstance(colliders, (tuple, list)) or not all(isinstance(c, COLLIDERS) for c in colliders):
        raise ValueError(f"colliders must be a tuple of cloth.Plane, cloth.Sphere or cloth.Capsule, got {colliders!r:.120}")
    for k, c in enumerate(colliders):
        check_scene_shapes(c, k, "draw one scene's or one step's colliders: "
                                 "jax.tree_util.tree_map(lambda a: a[t], colliders)")
    return tuple(colliders)


def _draw_colliders(ax, colliders, center, radius):
    """Spheres and capsules as light wireframes, planes as a translucent square."""
    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, 24), np.linspace(0, np.pi, 12))
    ball = np.stack([np.cos(u) * np.sin(v), np.cos(v), np.sin(u) * np.sin(v)], -1)
    for c in colliders:
        kind = type(c).__name__
        if kind == "Sphere":
            p = np.asarray(c.center) + float(c.radius) * ball
            ax.plot_surface(p[..., 0], p[..., 2], p[..., 1], color="0.7", alpha=0.35, linewidth=0.2, edgecolor="0.5")
        elif kind == "Capsule":
            for end in (np.asarray(c.a), np.asarray(c.b)):
                p = end + float(c.radius) * ball
                ax.plot_wireframe(p[..., 0], p[..., 2], p[..., 1], color="0.6", linewidth=0.3)
            seg = np.stack([np.asarray(c.a), np.asarray(c.b)])
            ax.plot(seg[:, 0], seg[:, 2], seg[:, 1], color="0.4", linewidth=2)
        elif kind == "Plane":
            n, o = np.asarray(c.normal), float(c.offset)
            a = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 0.0, 1.0])
            a /= np.linalg.norm(a)
            b = np.cross(n, a)
            p0 = center - (center @ n - o) * n
            s = np.linspace(-radius, radius, 2)
            A, B = np.meshgrid(s, s)
            P = p0 + A[..., None] * a + B[..., None] * b
            ax.plot_surface(P[..., 0], P[..., 2], P[..., 1], color="0.8", alpha=0.3, linewidth=0)


def plot_surface(x, triangles, colliders=(), ax=None, title: str = ""):
    """Draw the mesh ``triangles (F, 3)`` at positions ``x (N, 3)``, shaded, with the
    colliders.  Returns the figure."""
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

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
    c, r = world_limits(ax, x)
    _draw_colliders(ax, colliders, c, r)
    ax.add_collection3d(Poly3DCollection(_polys(x, T), facecolors=_shade(x, T), linewidths=0))
    ax.set_title(title)
    return ax.figure


def animate_surface(xs, triangles, path: str, colliders=(), fps: int = 30, stride: int = 1, title: str = "",
                    dpi: int = 60, elev: float = 20.0, azim: float = -60.0):
    """Write a GIF of the shaded mesh over ``xs (T, N, 3)``, with the (static) colliders.

    Returns the frame count.
    """
    from matplotlib.animation import PillowWriter
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    fps = check_fps(fps)
    xs = np.asarray(xs, np.float64)
    xs = check_frames("xs", xs, (xs.shape[-2] if xs.ndim == 3 else -1, 3))
    T = _check_triangles(triangles, xs.shape[1])
    colliders = _check_colliders(colliders)
    fig, ax = new_figure(4, 4, dpi=dpi, projection="3d")
    ax.view_init(elev=elev, azim=azim)
    c, r = world_limits(ax, xs.reshape(-1, 3))
    _draw_colliders(ax, colliders, c, r)
    surf = Poly3DCollection(_polys(xs[0], T), facecolors=_shade(xs[0], T), linewidths=0)
    ax.add_collection3d(surf)
    txt = ax.set_title(title)
    frames = range(0, len(xs), max(1, int(stride)))
    writer = PillowWriter(fps=fps)
    with writer.saving(fig, path, dpi):
        for t in frames:
            surf.set_verts(_polys(xs[t], T))
            surf.set_facecolor(_shade(xs[t], T))
            txt.set_text(f"{title}  step {t + 1}" if title else f"step {t + 1}")
            writer.grab_frame()
    return len(frames)
