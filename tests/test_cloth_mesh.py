"""Cloth from triangle meshes, and OBJ input/output (jaxsim.cloth._model.mesh, _obj)."""

import numpy as np
import pytest

from jaxsim import cloth as C


def pairs(a):
    return {tuple(sorted(map(int, p))) for p in np.asarray(a)}


def test_from_mesh_of_the_grid_triangulation_matches_grid_springs():
    n = 4
    g = C.grid(n, 0.1, dtype=np.float64)
    springs, kind = C.grid_springs(n)
    mesh = C.from_mesh(np.asarray(g.rest), C.grid_triangles(n), dtype=np.float64)
    edges, bend = C.mesh_springs(C.grid_triangles(n))
    structural, shear, skip = (pairs(springs[kind == k]) for k in (0, 1, 2))
    diagonals = pairs(edges) - structural
    # edges: the grid's structural springs plus one diagonal per cell (all shear springs)
    assert structural <= pairs(edges) and diagonals <= shear and len(diagonals) == n * n
    # bending across each diagonal joins the cell's other two corners: the other shear spring
    across = {b for b in pairs(bend) if b in shear}
    assert across | diagonals == shear and len(across) == n * n
    # where the definitions differ: bending across axis-aligned edges joins vertices a knight's
    # move apart, never the grid's skip-one (bending) springs
    others = pairs(bend) - shear
    assert not (others & skip)
    V = np.asarray(g.rest)
    d = np.abs(np.array([V[j] - V[i] for i, j in others]))[:, [0, 2]] / 0.1
    assert np.allclose(np.sort(d, axis=1), [1.0, 2.0])
    assert pairs(mesh.springs) == pairs(edges) | pairs(bend)


def test_lumped_masses_sum_to_area_times_density():
    V, T = C.disk(6, 0.5)
    c = C.from_mesh(V, T, density=0.3, dtype=np.float64)
    area = 0.5 * np.linalg.norm(np.cross(V[T[:, 1]] - V[T[:, 0]], V[T[:, 2]] - V[T[:, 0]]), axis=-1).sum()
    np.testing.assert_allclose(float(np.sum(c.mass)), 0.3 * area, rtol=1e-12)
    np.testing.assert_allclose(area, 0.5 * 36 * 0.5**2 * np.sin(2 * np.pi / 36), rtol=1e-12)  # the outer 36-gon
    assert not bool(np.any(c.pinned))


def test_mesh_springs_of_a_disk_satisfy_euler():
    V, T = C.disk(5, 1.0)
    edges, bend = C.mesh_springs(T)
    assert len(V) - len(edges) + len(T) == 1  # a disk
    assert len(bend) == len(edges) - 6 * 5  # one per interior edge


@pytest.mark.parametrize("tris, match", [
    ([[0, 1, 1]], "degenerate"),
    ([[0, 1, 2], [0, 1, 3]], "degenerate"),  # vertex 3 lies on the line 0-1
    ([[0, 1, 7]], r"\[0, 4\)"),
    ([[0, 1, 2], [0, 1, 2]], "non-manifold|same three"),
    ([[0, 1, 2], [1, 0, 4], [0, 1, 5]], "non-manifold"),
    ([[0, 1, 2]], "belong to no triangle"),
])
def test_bad_meshes_raise(tris, match):
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 0, 1], [2, 0, 0], [0.5, 0, -1], [0.5, 1, 0]], float)
    V = V[:4] if np.max(tris) >= 6 or np.max(tris) < 4 else V
    with pytest.raises(ValueError, match=match):
        C.from_mesh(V, np.asarray(tris))


def test_obj_round_trip_and_faces(tmp_path):
    V, T = C.disk(3, 0.7)
    p = C.write_obj(tmp_path / "d.obj", V, T)
    V2, T2 = C.read_obj(p)
    np.testing.assert_allclose(V2, V, atol=1e-9)
    np.testing.assert_array_equal(T2, T)
    quad = tmp_path / "q.obj"
    quad.write_text("# a quad\nv 0 0 0\nv 1 0 0\nv 1 0 1\nv 0 0 1\nvn 0 1 0\nf 1//1 2//1 3//1 -1//1\n")
    Vq, Tq = C.read_obj(quad)
    assert Vq.shape == (4, 3) and Tq.tolist() == [[0, 1, 2], [0, 2, 3]]
    paths = C.write_obj_sequence(tmp_path / "seq", np.stack([V, V + 1.0]), T)
    assert [p.rsplit("/", 1)[1] for p in paths] == ["frame_0000.obj", "frame_0001.obj"]
    np.testing.assert_allclose(C.read_obj(paths[1])[0], V + 1.0, atol=1e-9)


@pytest.mark.parametrize("text, match", [
    ("v 0 0\nf 1 2 3\n", "3 coordinates"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n", "out of range"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\n", "at least 3"),
    ("v 0 0 0\n", "no faces"),
    ("v 0 0 x\n", "bad vertex"),
])
def test_bad_obj_files_raise(tmp_path, text, match):
    p = tmp_path / "bad.obj"
    p.write_text(text)
    with pytest.raises(ValueError, match=match):
        C.read_obj(p)


def test_shipped_tablecloth_is_a_clean_disk():
    V, T = C.read_obj(C.TABLECLOTH_OBJ)
    assert V.shape == (331, 3) and T.shape == (600, 3)
    c = C.from_mesh(V, T)
    assert c.num_particles == 331 and np.allclose(np.asarray(c.rest)[:, 1], 0.0)


def test_surface_plot_and_gif(tmp_path):
    from jaxsim import viz

    V, T = C.disk(3, 0.5)
    xs = np.stack([V, V + [0.0, -0.1, 0.0]])
    cols = (C.Plane(np.array([0.0, 1.0, 0.0]), -0.5), C.Sphere(np.zeros(3), 0.2), C.Capsule(np.zeros(3), np.ones(3), 0.1))
    assert viz.animate_surface(xs, T, str(tmp_path / "s.gif"), colliders=cols) == 2
    assert (tmp_path / "s.gif").stat().st_size > 0
    viz.save(viz.plot_surface(V, T, cols), str(tmp_path / "s.png"))
    with pytest.raises(ValueError, match="triangles"):
        viz.plot_surface(V, T + len(V))


def test_surfaces_sort_cloth_and_colliders_together_and_stand_on_the_floor(tmp_path):
    """One depth-sorted collection holds the cloth's and the colliders' faces (a painter's
    sort of everything), the box stands on a floor plane, and a legend names what is drawn;
    GIFs are at least 480 px on their short side."""
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection
    from PIL import Image

    from jaxsim import viz

    V, T = C.disk(3, 0.5)
    V = V + [0.0, 0.6, 0.0]
    cols = (C.Plane(np.array([0.0, 1.0, 0.0]), 0.0), C.Sphere(np.array([0.0, 0.3, 0.0]), 0.2))
    fig = viz.plot_surface(V, T, cols)
    ax = fig.axes[0]
    polys = [c for c in ax.collections if isinstance(c, Poly3DCollection)]
    assert len(polys) == 1 and len(polys[0].get_facecolor()) > len(T)  # cloth and colliders in one sort
    assert ax.get_zlim()[0] == pytest.approx(-0.05 * (ax.get_zlim()[1] - ax.get_zlim()[0]) / 2, abs=1e-9)
    assert [t.get_text() for t in ax.get_legend().get_texts()] == ["cloth", "floor (plane)", "sphere"]
    viz.animate_surface(np.stack([V, V - [0.0, 0.1, 0.0]]), T, str(tmp_path / "s.gif"), colliders=cols)
    assert min(Image.open(tmp_path / "s.gif").size) >= 480
    assert viz.animate_surface(np.stack([V]), T, str(tmp_path / "d.gif"), dpi=50) == 1
    assert Image.open(tmp_path / "d.gif").size == (200, 200)  # an explicit dpi is kept
