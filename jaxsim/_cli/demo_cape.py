"""Demo section: a cape on the CMU walk (``cape.gif``), and the scene it runs, shared with
``benchmarks/cloth_character.py``."""

from __future__ import annotations

import dataclasses
import os

from ._timing import timed

#: The body's capsules on ``anim.cmu_walk`` (m): torso, collar bones, arms and legs.
CMU_BODY = {("Hips", "Chest2"): 0.12, ("Chest2", "LeftShoulder"): 0.05, ("Chest2", "RightShoulder"): 0.05,
            "LeftShoulder": 0.045, "LeftElbow": 0.04, "RightShoulder": 0.045, "RightElbow": 0.04,
            "LeftHip": 0.07, "LeftKnee": 0.05, "RightHip": 0.07, "RightKnee": 0.05}


@dataclasses.dataclass(frozen=True)
class Cape:
    """A cape pinned at the shoulders of a clip, ready for ``cloth.rollout``.

    Attributes:
      scene: the ``cloth.Cloth`` (its top row pinned, the body's capsules at time 0).
      state: its state at rest.
      pins: ``(T, n, 3)`` the top row's path (``rollout(pins=)``).
      colliders: the capsules' path (``rollout(colliders=)``), leaves ``(T, ...)``.
      triangles: ``(F, 3)`` the cape's triangles, for drawing.
      dt: the step (s).
    """

    scene: object
    state: object
    pins: object
    colliders: tuple
    triangles: object
    dt: float

    @property
    def steps(self) -> int:
        return int(self.pins.shape[0])


def cape(n: int = 24, seconds: float = 4.0, dt: float = 1 / 60, start: float = 4.0, wind=(0.0, 0.0, -0.5),
         drag: float = 0.3, lift: float = 0.1, width: float = 0.42, length: float = 0.62, body=None,
         dtype=None) -> Cape:
    """An ``n x n``-particle cape (``width x length`` m, 0.25 kg/m^2, k = 300 N/m) whose top
    row is fixed in the chest's frame (``anim.bone_points``) of ``anim.cmu_walk`` from
    ``start`` for ``seconds``, at ``dt``, with the body's capsules (``CMU_BODY``,
    ``anim.body_capsules``; ``body``: other ``{bone: radius}``) and a wind (``drag = lift = 0``:
    none)."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from .. import anim, cloth

    clip = anim.resample(anim.cmu_walk(), dt, start=start, duration=seconds)
    P = np.asarray(anim.positions(clip))
    chest = clip.skeleton.index("Chest2")
    left = P[0, clip.skeleton.index("LeftShoulder")] - P[0, clip.skeleton.index("RightShoulder")]
    left[1] = 0.0
    left /= np.linalg.norm(left)
    up = np.array([0.0, 1.0, 0.0])
    forward = np.cross(left, up)
    top = P[0, chest] + 0.09 * up - 0.16 * forward  # above the chest joint, behind the back
    across, down = np.linspace(-width / 2, width / 2, n), np.linspace(0.0, length, n)
    V = (top - down[:, None, None] * up + across[None, :, None] * left).reshape(-1, 3)
    pins = anim.bone_points(clip, chest, anim.bone_local(clip, chest, V[:n]))
    caps = anim.body_capsules(clip, CMU_BODY if body is None else body)
    T = cloth.grid_triangles(n - 1)
    on = drag > 0 or lift > 0
    dtype = np.dtype(dtype or jnp.zeros(()).dtype)
    scene = cloth.from_mesh(V.astype(dtype), T, stiffness=300.0, density=0.25, damping=0.01, gravity=9.8,
                            pins=list(range(n)), colliders=jax.tree.map(lambda a: a[0], caps),
                            wind=wind if on else None, drag=drag if on else None, lift=lift if on else None,
                            dtype=dtype)
    return Cape(scene, cloth.State.at_rest(scene), jnp.asarray(pins[1:], dtype),
                jax.tree.map(lambda a: jnp.asarray(a[1:], dtype), caps), T, dt)


def run_cape(c: Cape, integrator=None):
    """``(states, infos)`` of ``c``'s rollout."""
    from .. import cloth

    return cloth.rollout(c.scene, c.state, c.dt, c.steps, integrator or cloth.ImplicitEuler(), colliders=c.colliders,
                         pins=c.pins)


def min_distance(c: Cape, states) -> float:
    """The least signed distance (m) of any particle to the body over the returned states."""
    import jax
    import numpy as np

    x = states.x
    return min(float(np.min(np.asarray(jax.vmap(lambda col, xt: col.distance(xt))(col, x)))) for col in c.colliders)


def cape_section(out: str, fast: bool, lines: list[str]) -> None:
    import jax
    import numpy as np

    from .. import viz

    n, seconds = (10, 0.75) if fast else (24, 4.0)
    c = cape(n, seconds)
    print(f"[demo] cape: {n}x{n} cape on the CMU walk, {c.steps} steps, light wind ...", flush=True)
    (states, infos), compile_s, run_s = timed(lambda: run_cape(c), again=False)
    gap = min_distance(c, states)
    xs = np.concatenate([np.asarray(c.state.x)[None], np.asarray(states.x)])
    path = tuple(jax.tree.map(lambda a, b: np.concatenate([np.asarray(a)[None], np.asarray(b)]), c0, p)
                 for c0, p in zip(c.scene.colliders, c.colliders))
    viz.animate_surface(xs, c.triangles, os.path.join(out, "cape.gif"), colliders=path, stride=3 if fast else 4,
                        fps=15, title="a cape on the CMU walk", elev=12.0, azim=-35.0, follow=True)
    lines += ["## Cloth on a character: a cape pinned to the chest, body capsules, light wind", "",
              "| particles | steps | ms/step | compile (s) | mean Newton | converged | max substeps | "
              "min distance to body (m) | file |", "|---|---|---|---|---|---|---|---|---|",
              f"| {c.scene.num_particles} | {c.steps} | {1e3 * run_s / c.steps:.1f} | {compile_s:.1f} | "
              f"{float(np.mean(infos.newton_iters)):.1f} | {float(np.mean(infos.converged)):.0%} | "
              f"{int(np.max(infos.substeps))} | {gap:.1e} | cape.gif |", ""]
