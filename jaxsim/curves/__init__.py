"""Target trajectories for IK tracking: the lab's curves, each a ``(T, 3)`` array in the plane y = 0.

- ``_shapes``: the lab's shapes and ``from_function`` for any parametric curve;
- ``_resample``: ``resample_arclength``, equal chords along a polyline;
- ``_image``: ``from_image``, an image thinned to a skeleton and traced into strokes
  (``thin``, ``trace_strokes``).
"""

from ._image import from_image, thin, trace_strokes
from ._resample import resample_arclength
from ._shapes import CURVES, cardioid, circle, from_function, heart, square, star, triangle

__all__ = ["circle", "square", "triangle", "star", "cardioid", "heart", "from_function",
           "resample_arclength", "from_image", "thin", "trace_strokes", "CURVES"]
