"""Batches split across devices: 4 forced host devices in a subprocess, against one device."""

import os
import subprocess
import sys
import textwrap

import jax
import numpy as np
import pytest

from _compile_flags import with_fast_compile
from jaxsim import _sharding, cloth, ik

SCRIPT = textwrap.dedent("""
    import jax, numpy as np
    jax.config.update("jax_enable_x64", True)
    from jaxsim import cloth, ik
    assert jax.local_device_count() == 4, jax.devices()
    arm = ik.lab_arm()
    rng = np.random.default_rng(0)
    targets = np.asarray(arm.root) + rng.normal(size=(10_000, 1, 3))
    a = ik.solve(arm, targets, max_iters=20)                 # sharded by default on 4 devices
    b = ik.solve(arm, targets, max_iters=20, sharded=False)  # one device
    for name in ("rotations", "positions", "error"):
        x, y = getattr(a, name), getattr(b, name)
        assert len(x.sharding.device_set) == 4 and len(y.sharding.device_set) == 1, name
        assert x.sharding.shard_shape(x.shape)[0] == 2_500, x.sharding
        assert np.max(np.abs(np.asarray(x) - np.asarray(y))) <= 1e-6, name
    assert np.array_equal(np.asarray(a.iterations), np.asarray(b.iterations))
    odd = ik.solve(arm, targets[:9_999], max_iters=20)       # padded to 10_000, cut back
    assert odd.positions.shape == (9_999, 5, 3)
    assert np.max(np.abs(np.asarray(odd.positions) - np.asarray(b.positions[:9_999]))) <= 1e-6

    scenes = [cloth.replace(cloth.grid(4, 0.2), stiffness=k, damping=d)
              for k, d in zip(np.linspace(50, 400, 8), np.linspace(0.1, 1.0, 8))]
    s0 = cloth.State.at_rest(scenes[0])
    xs, infos = cloth.batch_rollout(scenes, s0, 1 / 60, 20)
    ys, _ = cloth.batch_rollout(scenes, s0, 1 / 60, 20, sharded=False)
    assert len(xs.x.sharding.device_set) == 4 and xs.x.sharding.shard_shape(xs.x.shape)[0] == 2
    assert np.max(np.abs(np.asarray(xs.x) - np.asarray(ys.x))) <= 1e-6
    assert bool(np.all(np.asarray(infos.converged)))
    nxt = cloth.State(xs.x[:, -1], xs.v[:, -1])              # a resumed chunk, sharded and not
    zs, zi = cloth.batch_rollout(scenes, nxt, 1 / 60, 3, resume=(xs, infos))
    ws, wi = cloth.batch_rollout(scenes, nxt, 1 / 60, 3, resume=(ys, infos), sharded=False)
    assert len(zs.x.sharding.device_set) == 4
    assert np.max(np.abs(np.asarray(zs.x) - np.asarray(ws.x))) <= 1e-6
    assert np.array_equal(np.asarray(zi.newton_iters), np.asarray(wi.newton_iters))
    print("OK")
""")


@pytest.mark.slow
def test_sharded_batches_match_one_device_on_4_forced_devices():
    env = with_fast_compile(dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=4", JAX_PLATFORMS="cpu"))
    r = subprocess.run([sys.executable, "-c", SCRIPT], env=env, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0 and "OK" in r.stdout, r.stderr[-3000:]


@pytest.mark.slow
@pytest.mark.skipif(jax.local_device_count() != 1, reason="checks the one-device path")
def test_one_device_places_nothing():
    assert _sharding.batch_mesh(None, 1000) is None
    with pytest.raises(ValueError, match="more than one"):
        _sharding.batch_mesh(True, 1000)
    arm = ik.lab_arm()
    res = ik.solve(arm, np.zeros((8, 1, 3)) + [0.5, 0.5, 0.5], max_iters=5)
    assert len(res.positions.sharding.device_set) == 1
    scenes = [cloth.grid(2, 0.2), cloth.grid(2, 0.2, stiffness=50.0)]
    xs, _ = cloth.batch_rollout(scenes, cloth.State.at_rest(scenes[0]), 1 / 60, 3)
    ref, _ = cloth.rollout(scenes[1], cloth.State.at_rest(scenes[1]), 1 / 60, 3)
    np.testing.assert_allclose(xs.x[1], ref.x, atol=1e-12)
    with pytest.raises(ValueError, match="cannot be batched"):
        cloth.stack_scenes([cloth.grid(2, 0.2), cloth.grid(3, 0.2)])
