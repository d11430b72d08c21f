"""One palette and line style for every drawing, and tidy 3D axes."""

from __future__ import annotations

#: Bones and chains; joints are discs of the same colour with a white centre.
BONE = "#1f4e79"
#: Effectors (rings) and their trails.
EFFECTOR = "#e07b00"
#: Targets (crosses).
TARGET = "#c0392b"
#: Target paths.
PATH = "0.55"
#: Cloth (shaded base colour), its wireframe, and pinned particles.
CLOTH = (0.25, 0.45, 0.85)
WIRE = "#2e6fb5"
PIN = TARGET
#: Colliders: spheres and capsules, planes.
SOLID = (0.72, 0.72, 0.70)
FLOOR = (0.80, 0.80, 0.78)
#: Limb width (points) and joint disc size.
LIMB, DISC = 4.5, 5.0


def joints(ax, u, v, *w, **kw):
    """Joint discs at ``(u, v[, w])``: filled white, ringed in the bone colour."""
    return ax.plot(u, v, *w, "o", mfc="white", mec=BONE, ms=DISC, mew=1.5, ls="none", **kw)


def limbs(ax, u, v, *w, **kw):
    """Thick round-capped bones (NaN-separated polylines)."""
    return ax.plot(u, v, *w, "-", color=BONE, lw=LIMB, solid_capstyle="round", **kw)


def tidy_3d(ax) -> None:
    """Few ticks, small labels, and room for the axis labels on 3D axes."""
    ax.locator_params(nbins=4)
    ax.tick_params(labelsize=7, pad=0)
    for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
        axis.labelpad = 2
        axis.label.set_size(8)
    ax.set_box_aspect((1, 1, 1), zoom=0.88)


def legend(ax, **kw):
    """A small legend in the upper right, on a translucent box."""
    kw = {"loc": "upper right", "fontsize": 7, "framealpha": 0.8, **kw}
    return ax.legend(**kw)
