"""Wavefront OBJ input and output for triangle meshes, in plain Python."""

from __future__ import annotations

import os

import numpy as np

#: A circular tablecloth shipped with the package: a flat disk of radius 0.8 m in the
#: plane y = 0, 10 rings, 331 vertices, 600 near-equilateral triangles.
TABLECLOTH_OBJ = os.path.join(os.path.dirname(os.path.dirname(__file__)), "data", "tablecloth.obj")


def read_obj(path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and triangles of an OBJ file.

    Reads ``v x y z`` and ``f`` lines (``f 1 2 3``, ``f 1/1 2/2 3/3``, ``f 1//1 ...``,
    negative ids counted from the end); faces with more than three vertices are split
    into a fan.  Everything else (normals, texture coordinates, groups, materials) is
    skipped.

    Returns:
      ``(vertices (N, 3) float64, triangles (F, 3) int32)``, 0-based.

    The file is read as UTF-8; bytes that are not (a latin-1 comment, say) are replaced,
    which can only matter inside comments and names, since numbers are ASCII.

    Raises:
      ValueError: a malformed ``v`` or ``f`` line (with its line number), a NaN or
        infinite coordinate, a face id out of range, or a file without faces.
    """
    verts, tris = [], []
    with open(path, encoding="utf-8", errors="replace") as fh:
        for lineno, line in enumerate(fh, 1):
            parts = line.split("#", 1)[0].split()
            if not parts:
                continue
            if parts[0] == "v":
                try:
                    verts.append([float(t) for t in parts[1:4]])
                except ValueError:
                    raise ValueError(f"{path}:{lineno}: bad vertex line {line.strip()!r}") from None
                if len(verts[-1]) != 3:
                    raise ValueError(f"{path}:{lineno}: a vertex needs 3 coordinates")
                if not all(np.isfinite(verts[-1])):
                    raise ValueError(f"{path}:{lineno}: vertex {len(verts)} has a NaN or infinite coordinate: "
                                     f"{line.strip()!r}")
            elif parts[0] == "f":
                try:
                    ids = [int(t.split("/")[0]) for t in parts[1:]]
                except ValueError:
                    raise ValueError(f"{path}:{lineno}: bad face line {line.strip()!r}") from None
                if len(ids) < 3:
                    raise ValueError(f"{path}:{lineno}: a face needs at least 3 vertices")
                n = len(verts)
                ids = [i - 1 if i > 0 else n + i for i in ids]
                if min(ids) < 0 or max(ids) >= n:
                    raise ValueError(f"{path}:{lineno}: face ids out of range (1..{n} so far)")
                tris += [(ids[0], ids[k], ids[k + 1]) for k in range(1, len(ids) - 1)]
    if not tris:
        raise ValueError(f"{path}: no faces")
    return np.asarray(verts, np.float64).reshape(-1, 3), np.asarray(tris, np.int32)


def write_obj(path, x, triangles) -> str:
    """Write positions ``x (N, 3)`` and ``triangles (F, 3)`` (0-based) as an OBJ file.

    Returns the path written.
    """
    x = np.asarray(x, np.float64)
    T = np.asarray(triangles)
    if x.ndim != 2 or x.shape[1] != 3:
        raise ValueError(f"x must have shape (N, 3), got {x.shape}")
    if not np.all(np.isfinite(x)):
        bad = np.flatnonzero(~np.all(np.isfinite(x), axis=1))
        raise ValueError(f"x has {bad.size} vertices with NaN or infinite coordinates (first id {bad[0]}); "
                         "an OBJ file cannot hold them")
    if T.size and (T.dtype == np.bool_ or not np.issubdtype(T.dtype, np.integer)):
        raise ValueError(f"triangles must hold integer vertex ids, got dtype {T.dtype}")
    if T.ndim != 2 or T.shape[1] != 3 or (T.size and (T.min() < 0 or T.max() >= len(x))):
        raise ValueError(f"triangles must be (F, 3) ids in [0, {len(x)})")
    lines = ["# jaxsim cloth", *(f"v {a:.9g} {b:.9g} {c:.9g}" for a, b, c in x),
             *(f"f {a + 1} {b + 1} {c + 1}" for a, b, c in T)]
    with open(path, "w", encoding="utf-8") as fh:
        fh.write("\n".join(lines) + "\n")
    return str(path)


def write_obj_sequence(folder, xs, triangles, stem: str = "frame") -> list[str]:
    """One OBJ per frame of ``xs (T, N, 3)``: ``folder/stem_0000.obj``, ... (a numbered
    sequence that Blender's and MeshLab's importers open as an animation).

    Returns the paths written.
    """
    if not isinstance(stem, str) or not stem or os.sep in stem or (os.altsep and os.altsep in stem) or stem in (".", ".."):
        raise ValueError(f"stem must be a plain file-name prefix without path separators, got {stem!r}; "
                         "put the folder in folder=")
    xs = np.asarray(xs)
    if xs.ndim != 3 or xs.shape[2] != 3:
        raise ValueError(f"xs must have shape (T, N, 3), got {xs.shape}")
    os.makedirs(folder, exist_ok=True)
    width = max(4, len(str(len(xs) - 1)))
    return [write_obj(os.path.join(folder, f"{stem}_{t:0{width}d}.obj"), x, triangles) for t, x in enumerate(xs)]
