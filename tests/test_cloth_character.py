"""Cloth on a moving character: a cape pinned to the CMU walk's chest (``anim.bone_points``),
colliding with its capsules (``anim.body_capsules``), in a wind: pins on their path, no
penetration of the moving body, and gradients through the rollout."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from jaxsim import cloth as C
from jaxsim._cli.demo_cape import cape, min_distance, run_cape

jax.config.update("jax_enable_x64", True)

CAPE = cape(6, 0.25, dtype=np.float64)


@pytest.mark.slow
def test_the_cape_follows_its_pins_and_stays_outside_the_moving_body():
    states, infos = run_cape(CAPE)
    assert CAPE.steps == 15 and bool(jnp.all(infos.converged))
    assert np.abs(np.asarray(states.x)[:, :6] - np.asarray(CAPE.pins)).max() <= 1e-12
    assert min_distance(CAPE, states) > 0.0
    # the cape is carried along with the walker (about 1 m/s along +z)
    assert float(states.x[-1, :, 2].mean() - CAPE.state.x[:, 2].mean()) > 0.05


@pytest.mark.slow
def test_gradients_of_a_cape_rollout_in_stiffness_and_wind():
    short = cape(5, 3 / 60, dtype=np.float64)

    def final(k, wind):
        scene = C.replace(short.scene, stiffness=short.scene.stiffness * k, wind=wind)
        states, _ = C.rollout(scene, short.state, short.dt, short.steps, colliders=short.colliders, pins=short.pins)
        return jnp.sum(states.x[-1, :, 2]) + jnp.sum(states.x[-1, :, 1] ** 2)

    check_grads(final, (jnp.asarray(1.0), jnp.asarray([0.2, 0.0, -0.5])), order=1, modes=("rev",), eps=1e-6)
