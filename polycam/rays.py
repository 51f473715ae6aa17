"""Ray bundles: origins and unit directions in one named frame.

See docs/conventions.md: a ray ``(o, d)`` looks along ``d`` from ``o``; the
scene is at ``o + s d`` for ``s > 0``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .geometry import rotate_vectors, transform_points

__all__ = ["RayBundle"]


@dataclass(frozen=True)
class RayBundle:
    """A batch of rays in one frame.

    Leading batch dims ``*B`` are shared by both fields; broadcasting follows numpy.
    """

    origins: np.ndarray
    """(*B, 3) [m]: ray origins in ``frame``."""
    directions: np.ndarray
    """(*B, 3) unit vectors: viewing directions in ``frame``."""
    frame: str = "rig"
    """Name of the frame the rays are expressed in (``"rig"``, ``"world"``, ``"cam00"``, ...)."""

    def __post_init__(self) -> None:
        if self.origins.shape[-1:] != (3,) or self.directions.shape[-1:] != (3,):
            raise ValueError("RayBundle: origins and directions need a trailing axis of 3")

    @property
    def shape(self) -> tuple[int, ...]:
        return np.broadcast_shapes(self.origins.shape, self.directions.shape)[:-1]

    def transformed(self, T_new_old: np.ndarray, frame: str) -> "RayBundle":
        """The same rays expressed in another frame; ``T_new_old`` is (4, 4)."""
        return RayBundle(
            origins=transform_points(T_new_old, self.origins),
            directions=rotate_vectors(np.asarray(T_new_old)[:3, :3], self.directions),
            frame=frame,
        )

    def reshape(self, *shape: int) -> "RayBundle":
        return RayBundle(self.origins.reshape(*shape, 3), self.directions.reshape(*shape, 3), self.frame)

    def points_at(self, s: np.ndarray) -> np.ndarray:
        """Points ``o + s d`` (*B, 3) at distances ``s`` (*B) along the rays."""
        return self.origins + np.asarray(s)[..., None] * self.directions
