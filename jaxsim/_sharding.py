"""Splitting a batch across local devices with JAX's own sharding (``Mesh``, ``NamedSharding``).

The batched entry points place their inputs on a 1-D mesh over ``jax.local_devices()``
with the batch axis split, and let XLA's SPMD partitioner run the compiled solver on
every shard.  On one device nothing is placed and nothing changes.  A batch that does
not divide evenly is padded by repeating its last element, and the padding is cut
from the results.

Several hosts: start every process with ``jax.distributed.initialize(...)``; each
process then solves its own slice of the targets on its local devices (pass that
slice to the entry point), which is the data-parallel pattern the solvers need.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

AXIS = "batch"


def batch_mesh(sharded: bool | None, n: int) -> Mesh | None:
    """The 1-D mesh to split a batch of ``n`` over, or ``None`` for no sharding.

    Args:
      sharded: ``None`` shards when there are several local devices and ``n >= 2``;
        ``True`` requires it to be possible (raises ``ValueError`` on one device);
        ``False`` never shards.
    """
    devices = jax.local_devices()
    if sharded is False or (sharded is None and (len(devices) == 1 or n < 2)):
        return None
    if len(devices) == 1:
        raise ValueError("sharded=True needs more than one local device")
    return Mesh(np.asarray(devices), (AXIS,))


def shard_leading(tree, mesh: Mesh, n: int):
    """Pad every leaf's leading axis ``n`` to a multiple of the mesh size and split it.

    Returns ``(tree, pad)``; cut results with :func:`unpad`.
    """
    d = mesh.devices.size
    pad = (-n) % d

    def put(a):
        a = jnp.asarray(a)
        if pad:
            a = jnp.concatenate([a, jnp.repeat(a[-1:], pad, axis=0)], axis=0)
        spec = PartitionSpec(AXIS, *([None] * (a.ndim - 1)))
        return jax.device_put(a, NamedSharding(mesh, spec))

    return jax.tree_util.tree_map(put, tree), pad


def unpad(tree, pad: int):
    """Drop ``pad`` trailing entries of every leaf's leading axis."""
    if not pad:
        return tree
    return jax.tree_util.tree_map(lambda a: a[:-pad] if a is not None else None, tree)
