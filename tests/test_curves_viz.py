import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

from jaxsim import curves, ik
from jaxsim.curves import thin, trace_strokes

viz = pytest.importorskip("jaxsim.viz")


def chords(p, closed):
    q = np.vstack([p, p[:1]]) if closed else p
    return np.linalg.norm(np.diff(q, axis=0), axis=1)


@pytest.mark.parametrize("name", ["heart", "star"])
def test_resample_arclength_even_on_heart_and_star(name):
    pts = curves.CURVES[name]()
    c = chords(pts, closed=True)
    assert c.max() / c.min() <= 1.05
    # from a sparse, very uneven sampling of the same closed shape
    rng = np.random.default_rng(0)
    keep = np.sort(rng.choice(len(pts), size=len(pts) // 3, replace=False))
    uv = pts[keep][:, [0, 2]]
    raw = chords(uv, closed=True)
    assert raw.max() / raw.min() > 3  # the input really is uneven
    out = curves.resample_arclength(uv, 120, closed=True)
    c = chords(out, closed=True)
    assert out.shape == (120, 2) and c.max() / c.min() <= 1.05
    np.testing.assert_allclose(out[0], uv[0])


def test_resample_open_polyline_keeps_ends_and_rejects_bad_input():
    p = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 0.1], [3.0, 2.0]])
    out = curves.resample_arclength(p, 50)
    c = chords(out, closed=False)
    assert c.max() / c.min() <= 1.0 + 1e-6
    np.testing.assert_allclose(out[[0, -1]], p[[0, -1]], atol=1e-9)
    with pytest.raises(ValueError):
        curves.resample_arclength(np.zeros((3, 2)), 10)
    with pytest.raises(ValueError):
        curves.resample_arclength(p, 1)


def test_builtin_curves_shapes_and_reach():
    sizes = {"star": 400}
    arm = ik.lab_arm()
    for name, make in curves.CURVES.items():
        pts = make()
        assert pts.shape == (sizes.get(name, 150), 3), name
        assert np.all(pts[:, 1] == 0.0)
        assert np.all(np.linalg.norm(pts - np.asarray(arm.root), axis=1) < float(arm.reach))
    sq = curves.square()
    assert np.isclose(np.ptp(sq[:, 0]), 0.4) and np.isclose(np.ptp(sq[:, 2]), 0.4)
    assert np.isclose(np.max(np.linalg.norm(curves.star()[:, [0, 2]], axis=1)), 0.4)
    f = curves.from_function(lambda t: (np.cos(t), np.sin(t)), np.linspace(0, 1, 7))
    assert f.shape == (7, 3)
    with pytest.raises(ValueError):
        curves.from_function(lambda t: t, np.linspace(0, 1, 7))


@pytest.fixture(scope="module")
def digit():
    return viz.render_text("8", px=64)


def test_from_image_traces_every_skeleton_pixel_without_long_jumps(digit):
    from scipy import ndimage

    sk = thin(digit > 0.5)
    assert 30 < sk.sum() < (digit > 0.5).sum()
    strokes = trace_strokes(sk)
    path = np.concatenate(strokes)
    # every skeleton pixel lies on (within 1 px of) the traced path
    pix = np.argwhere(sk)
    d = np.min(np.linalg.norm(pix[:, None, :] - path[None, :, :], axis=-1), axis=1)
    assert d.max() <= 1.0
    # within a stroke the pen moves to 8-neighbours only
    for s in strokes:
        assert np.all(np.linalg.norm(np.diff(s, axis=0), axis=1) <= np.sqrt(2) + 1e-12)
    # the pen lifts only between separate pieces of the skeleton
    _, pieces = ndimage.label(sk, structure=np.ones((3, 3)))
    assert len(strokes) == pieces
    traj = curves.from_image(digit)
    assert traj.shape == (len(path), 3) and np.max(np.abs(traj)) <= 0.6 + 1e-12


def test_from_image_two_pieces_one_jump_of_the_gap():
    img = np.zeros((20, 30))
    img[5, 2:10] = 1.0
    img[5, 15:25] = 1.0  # a gap of 5 px between the two strokes
    strokes = trace_strokes(thin(img > 0.5))
    assert len(strokes) == 2
    jump = np.linalg.norm(strokes[1][0] - strokes[0][-1])
    assert jump == pytest.approx(6.0)  # from column 9 to column 15
    with pytest.raises(ValueError):
        curves.from_image(np.zeros((8, 8)))
    with pytest.raises(ValueError):
        curves.from_image(np.zeros(8))


def nonblank(path):
    a = np.asarray(Image.open(path).convert("L"), np.float64)
    return np.mean(a < 200)  # fraction of inked pixels


def test_plots_and_animations_write_real_images(tmp_path, digit):
    arm = ik.lab_arm()
    targets = curves.circle(12)
    res = ik.track(arm, targets[:, None])
    fig = viz.plot_chain(res.positions[0], targets[0])
    p = viz.save(fig, str(tmp_path / "chain.png"))
    w, h = fig.get_size_inches() * fig.dpi
    assert Image.open(p).size == (int(round(w)), int(round(h))) and nonblank(p) > 0.005
    p = viz.save(viz.plot_tracking(res, targets, title="circle"), str(tmp_path / "track.png"))
    assert nonblank(p) > 0.01
    n = viz.animate_tracking(res, targets, str(tmp_path / "track.gif"), stride=2, dpi=50)
    im = Image.open(tmp_path / "track.gif")
    assert n == 6 and im.n_frames == 6 and im.size == (200, 200)
    frames = []
    for k in range(im.n_frames):
        im.seek(k)
        frames.append(np.asarray(im.convert("L"), np.float64))
    assert all(np.mean(f < 200) > 0.005 for f in frames)
    assert np.abs(frames[0] - frames[-1]).max() > 0  # the chain moves
    n = viz.animate_tracking(res, targets, str(tmp_path / "track3d.gif"), stride=4, plane="3d")
    im = Image.open(tmp_path / "track3d.gif")
    assert n == 3 and im.n_frames == 3 and min(im.size) >= 480  # the arm hanging from 1.7 m, slide-sized
    with pytest.raises(ValueError, match="3d"):
        viz.animate_tracking(res, targets, str(tmp_path / "x.gif"), plane="top")

    from jaxsim import cloth

    c = cloth.grid(4, 0.2)
    xs = np.stack([np.asarray(c.rest), np.asarray(c.rest) - [0.0, 0.1, 0.0]])
    p = viz.save(viz.plot_cloth(c, xs[-1]), str(tmp_path / "cloth.png"))
    assert nonblank(p) > 0.01
    n = viz.animate_cloth(c, xs, str(tmp_path / "cloth.gif"), dpi=40)
    im = Image.open(tmp_path / "cloth.gif")
    assert n == 2 and im.n_frames == 2 and im.size == (160, 160)
    p = viz.save(viz.plot_error_vs_time({"a": ([1e-3, 1e-2], [1e-2, 1e-6])}), str(tmp_path / "pareto.png"))
    assert nonblank(p) > 0.01


def test_import_jaxsim_does_not_import_matplotlib():
    code = "import sys, jaxsim, jaxsim.curves; assert 'matplotlib' not in sys.modules, 'matplotlib imported'"
    subprocess.run([sys.executable, "-c", code], check=True)


def test_plot_and_animate_skeleton(tmp_path):
    from jaxsim import viz

    H = ik.humanoid(limits=False)
    eff = [H.index(n) for n in ik.HUMANOID_EFFECTORS]
    P = np.asarray(ik.fk(H).positions)
    for views in (("front", "side"), "3d", ("side",)):
        fig = viz.plot_skeleton(H, P, effectors=eff, targets=P[eff] + 0.1, trails=np.stack([P[eff]] * 3), views=views)
        assert len(fig.axes) == (1 if views == "3d" else len(views))
    frames = np.stack([P, P + [0.0, 0.1, 0.0], P + [0.0, 0.2, 0.0]])
    n = viz.animate_skeleton(H, frames, str(tmp_path / "h.gif"), effectors=eff, targets=frames[:, eff])
    im = Image.open(tmp_path / "h.gif")
    assert n == 3 and im.n_frames == 3 and min(im.size) >= 480  # slide-sized by default
    fig = viz.plot_skeleton(H, P, effectors=eff, targets=P[eff] + 0.1, trails=np.stack([P[eff]] * 3))
    assert [t.get_text() for t in fig.legends[0].get_texts()] == ["bones", "joints", "root", "effectors", "targets",
                                                                  "effector paths"]
    with pytest.raises(ValueError, match="views"):
        viz.plot_skeleton(H, P, views=("top",))
    with pytest.raises(ValueError, match="positions"):
        viz.animate_skeleton(H, P, str(tmp_path / "x.gif"))
    with pytest.raises(ValueError, match="targets"):
        viz.animate_skeleton(H, frames, str(tmp_path / "x.gif"), effectors=eff, targets=frames[:, :2])
