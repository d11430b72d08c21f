"""The IK model: the ``Skeleton`` pytree (a tree of joints; a chain is one) and its static topology.

A skeleton is a tree of ``J`` ball joints in topological order (``parents[i] < i``).
Forward kinematics is the lab's recursion with "parent" read from ``parents``; a chain
(:func:`Chain`, the lab's arm) is the skeleton with ``parents = (-1, 0, 1, ..., J-2)``.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

from ..._dataclass import is_concrete, pytree_dataclass, static_field
from ..._dtype import as_float, check_array_dtype, tiny
from ..._validate import check_finite
from .limits import SwingTwist, check_limits


def _check_parents(parents) -> tuple:
    try:
        raw = list(parents)
    except TypeError:
        raise ValueError(f"parents must be a sequence of ints, got {parents!r}") from None
    for i, q in enumerate(raw):
        if isinstance(q, (bool, np.bool_)) or not isinstance(q, (int, np.integer)):
            raise ValueError(f"parents must be ints, got parents[{i}] = {q!r} ({type(q).__name__})")
    p = tuple(int(i) for i in raw)
    if len(p) < 2:
        raise ValueError(f"a Skeleton needs at least 2 joints (one bone), got {len(p)}")
    if p[0] != -1:
        raise ValueError(f"parents[0] must be -1 (joint 0 is the root), got {p[0]}")
    for i, q in enumerate(p[1:], start=1):
        if q == -1:
            raise ValueError(f"joint {i} has parent -1: a second root (only joint 0 may be a root)")
        if not 0 <= q < i:
            raise ValueError(f"parents[{i}] = {q} is out of order or out of range: need 0 <= parents[i] < i "
                             f"(joints in topological order)")
    return p


@pytree_dataclass
class Skeleton:
    """A tree of ``J`` ball joints.

    Attributes:
      parents: static tuple of ``J`` ints; ``parents[0] = -1`` and ``0 <= parents[i] < i``.
      offsets: ``(J, 3)``: ``offsets[0]`` is the root's world position, ``offsets[i]``
        joint ``i``'s offset from its parent in the parent's frame (the lab's
        ``LocalOffset``; scene units, metres for :func:`jaxsim.ik.humanoid`).
      names: optional static tuple of ``J`` distinct joint names.
      limits: optional static tuple of ``J`` joint limits (``ik.Hinge``, ``ik.SwingTwist``,
        ``ik.Fixed``, or ``None``/``ik.Free`` for a free joint); ``None`` = all free.
        Every solver returns poses within them (see ``jaxsim.ik._model.limits``).

    Raises:
      ValueError: on wrong shapes, fewer than 2 joints, a parent out of order or out of
        range, a second root, non-finite values, duplicate names,
        limits for a different number of joints, a half-precision dtype, or a skeleton
        too large for its dtype (squared distances across it must not overflow: about
        4e18 scene units in float32).
    """

    parents: tuple = static_field()
    offsets: jax.Array
    names: tuple | None = static_field(default=None)
    limits: tuple | None = static_field(default=None)

    def __post_init__(self):
        object.__setattr__(self, "parents", _check_parents(self.parents))
        object.__setattr__(self, "limits", check_limits(self.limits, self.parents))
        if self.names is not None:
            names = tuple(str(n) for n in self.names)
            if len(names) != len(self.parents):
                raise ValueError(f"names has {len(names)} entries for {len(self.parents)} joints")
            if len(set(names)) != len(names):
                raise ValueError("joint names must be distinct")
            object.__setattr__(self, "names", names)
        if not is_concrete(self.offsets):
            return  # rebuilt inside a transformation: leaves are tracers or placeholders
        a = np.asarray(self.offsets)
        J = len(self.parents)
        if a.shape != (J, 3):
            raise ValueError(f"Skeleton offsets must have shape ({J}, 3) for {J} joints, got {a.shape}")
        check_array_dtype("Skeleton", a.dtype)
        check_finite("Skeleton offsets", a)
        offsets = as_float(self.offsets)
        dtype = offsets.dtype
        lengths = np.linalg.norm(a[1:].astype(np.float64), axis=-1)
        for i, lim in enumerate(self.limits or ()):
            kids = self.children[i]
            bone = kids[0] if kids else i
            if isinstance(lim, SwingTwist) and lim.axis is None and bone > 0 and lengths[bone - 1] <= tiny(dtype):
                raise ValueError(f"joint {i}'s SwingTwist takes its twist axis from bone {bone}, which has zero length; "
                                 "give it axis=")
        span = float(np.abs(a[0].astype(np.float64)).max() + lengths.sum())
        limit = float(np.sqrt(np.finfo(dtype).max)) / 8
        if span >= limit:
            raise ValueError(f"Skeleton spans {span:.3g} scene units, too large for {dtype} (squared distances "
                             f"overflow beyond {limit:.2g}); use float64 or smaller units")
        object.__setattr__(self, "offsets", offsets)

    def with_limits(self, limits) -> Skeleton:
        """The same skeleton with ``limits`` (one per joint, or ``None`` for none)."""
        return dataclasses.replace(self, limits=limits)

    def zero_length_joints(self) -> tuple:
        """Joints whose offset from their parent is zero (shorter than ``_dtype.tiny``), as
        in most BVH rigs (CMU's hip, collar and hand joints).  FK takes them; the IK solvers
        do not (``ValueError`` at their boundary).  Empty when the offsets are traced."""
        if not is_concrete(self.offsets):
            return ()
        a = np.asarray(self.offsets, np.float64)
        return tuple(int(i) + 1 for i in np.flatnonzero(np.linalg.norm(a[1:], axis=-1) <= tiny(self.offsets.dtype)))

    @property
    def num_joints(self) -> int:
        """``J`` (a static Python int)."""
        return len(self.parents)

    @property
    def root(self) -> jax.Array:
        """``(3,)`` world position of the root joint."""
        return self.offsets[0]

    @property
    def children(self) -> tuple:
        """Per joint, the tuple of its children."""
        return children_of(self.parents)

    @property
    def leaves(self) -> tuple:
        """Joints with no children, in order (the default effectors)."""
        return tuple(i for i, c in enumerate(self.children) if not c)

    @property
    def is_chain(self) -> bool:
        """Whether every joint's parent is the joint before it (a serial chain)."""
        return self.parents == chain_parents(self.num_joints)

    @property
    def lengths(self) -> jax.Array:
        """``(J-1,)`` bone lengths: ``lengths[i-1] = |offsets[i]|``."""
        o = self.offsets[1:]
        return jnp.sqrt(jnp.sum(o * o, axis=-1))

    @property
    def reach(self) -> jax.Array:
        """``()`` the longest root-to-joint path length (a chain's total length)."""
        acc = [jnp.zeros((), self.offsets.dtype)]
        lengths = self.lengths
        for i, p in enumerate(self.parents[1:], start=1):
            acc.append(acc[p] + lengths[i - 1])
        return functools.reduce(jnp.maximum, acc)

    def index(self, name: str) -> int:
        """Joint id of ``name``."""
        if self.names is None or name not in self.names:
            raise ValueError(f"no joint named {name!r}" + ("" if self.names is None else f"; names: {self.names}"))
        return self.names.index(name)

    def rest_rotations(self) -> jax.Array:
        """``(J, 4)`` identity local rotations, in the skeleton's dtype."""
        return jnp.zeros((self.num_joints, 4), self.offsets.dtype).at[:, 0].set(1.0)


def chain_parents(J: int) -> tuple:
    """``(-1, 0, 1, ..., J-2)``: the parents of a serial chain of ``J`` joints."""
    return (-1,) + tuple(range(J - 1))


def steps_below(parents: tuple, x: int, j: int) -> int | None:
    """How many joints down from ``j`` the joint ``x`` hangs (0 when ``x`` is ``j``), or
    ``None`` when ``j`` is neither ``x`` nor one of its ancestors."""
    n = 0
    while x >= 0:
        if x == j:
            return n
        x, n = parents[x], n + 1
    return None


@functools.lru_cache(maxsize=None)
def children_of(parents: tuple) -> tuple:
    kids = [[] for _ in parents]
    for i, p in enumerate(parents[1:], start=1):
        kids[p].append(i)
    return tuple(tuple(k) for k in kids)


@dataclasses.dataclass(frozen=True)
class Topology:
    """What the solvers need to know about a tree and its effectors (all static).

    Attributes:
      parents: as in ``Skeleton``.
      effectors: effector joint ids, ``E`` of them.
      active: joints on some root-to-effector path (ancestor-closed), increasing.
      active_children: per joint, its active children.
      below: per joint, the effector slots ``k`` whose joint lies strictly below it.
      effector_slot: per joint, its effector slot or -1.
      path: per effector slot, the joints from the root to the effector.
    """

    parents: tuple
    effectors: tuple
    active: tuple
    active_children: tuple
    below: tuple
    effector_slot: tuple
    path: tuple

    @property
    def is_chain_end(self) -> bool:
        """A serial chain whose one effector is its last joint (the lean chain kernels' case)."""
        J = len(self.parents)
        return self.parents == chain_parents(J) and self.effectors == (J - 1,)

    @property
    def moving(self) -> tuple:
        """Joints whose local rotation a solver may change: an effector strictly below."""
        return tuple(i for i in range(len(self.parents)) if self.below[i])


@functools.lru_cache(maxsize=None)
def topology(parents: tuple, effectors: tuple) -> Topology:
    J = len(parents)
    paths = []
    for e in effectors:
        p, j = [], e
        while j != -1:
            p.append(j)
            j = parents[j]
        paths.append(tuple(reversed(p)))
    active = sorted({j for p in paths for j in p} | {0})
    act = set(active)
    below = [[] for _ in range(J)]
    for k, p in enumerate(paths):
        for j in p[:-1]:
            below[j].append(k)
    slot = [-1] * J
    for k, e in enumerate(effectors):
        slot[e] = k
    kids = children_of(parents)
    return Topology(
        parents=parents,
        effectors=effectors,
        active=tuple(active),
        active_children=tuple(tuple(c for c in kids[i] if c in act) for i in range(J)),
        below=tuple(tuple(b) for b in below),
        effector_slot=tuple(slot),
        path=tuple(paths),
    )


def check_effectors(skeleton: Skeleton, effectors) -> tuple:
    """Effector ids as a tuple of ints (default: the leaves); ``ValueError`` on bad ids."""
    if effectors is None:
        return skeleton.leaves
    if isinstance(effectors, (int, np.integer, str)):
        effectors = (effectors,)
    out = []
    for e in effectors:
        if isinstance(e, str):
            e = skeleton.index(e)
        if isinstance(e, bool) or not isinstance(e, (int, np.integer)):
            raise ValueError(f"effectors must be joint ids or names, got {e!r}")
        if not 0 <= int(e) < skeleton.num_joints:
            raise ValueError(f"effector id {int(e)} is out of range for {skeleton.num_joints} joints")
        out.append(int(e))
    if not out:
        raise ValueError("effectors must name at least one joint")
    if len(set(out)) != len(out):
        raise ValueError(f"effectors must be distinct, got {out}")
    return tuple(out)
