"""The one equirectangular convention of snell_bench.

Convention:
    A panorama has ``width = 2 * height``. Directions are expressed in the *panorama frame*, whose
    axes follow OpenCV (x right, y down, z forward); :class:`PanoramaCamera` maps them to the
    camera frame.

    - longitude ``lon = atan2(x, z)`` in ``(-pi, pi]``: 0 looks forward (+z), +pi/2 right (+x);
    - latitude ``lat = atan2(-y, hypot(x, z))`` in ``[-pi/2, pi/2]``: +pi/2 is straight up (-y);
    - pixel ``u = (lon / 2pi + 0.5) * W - 0.5``, ``v = (0.5 - lat / pi) * H - 0.5`` with integer
      values at pixel centres (the :mod:`snell_bench.scene.camera` convention). The forward
      direction sits between the two middle columns, up is the top row, and ``u`` wraps around at
      ``-0.5 / W - 0.5``.

    Functions accept numpy arrays or torch tensors and return the same kind.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

try:  # torch is a hard dependency of the package, but keep this module importable on its own
    import torch
except ImportError:  # pragma: no cover
    torch = None

__all__ = ["PanoramaCamera", "direction_to_equirect", "equirect_to_direction", "equirect_grid"]


def _is_torch(x) -> bool:
    return torch is not None and isinstance(x, torch.Tensor)


def direction_to_equirect(d, height: int):
    """Panorama-frame directions to pixel coordinates.

    Args:
        d: ``(..., 3)`` directions (any length > 0), numpy or torch.
        height: panorama height ``H`` (its width is ``2 H``).

    Returns:
        ``(..., 2)`` pixel coordinates ``(u, v)``, the same kind as ``d``.

    Examples:
        Forward is the centre of the panorama (between the middle pixels), up its top edge:

        >>> direction_to_equirect(np.array([0.0, 0.0, 1.0]), 4).tolist()
        [3.5, 1.5]
        >>> [round(float(v), 4) for v in direction_to_equirect(torch.tensor([1.0, -1.0, 0.0]), 4)]
        [5.5, 0.5]
    """
    W, H = 2 * height, height
    if _is_torch(d):
        x, y, z = d.unbind(-1)
        lon = torch.atan2(x, z)
        lat = torch.atan2(-y, torch.hypot(x, z))
        return torch.stack([(lon / (2 * math.pi) + 0.5) * W - 0.5, (0.5 - lat / math.pi) * H - 0.5], -1)
    d = np.asarray(d)
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    lon = np.arctan2(x, z)
    lat = np.arctan2(-y, np.hypot(x, z))
    return np.stack([(lon / (2 * np.pi) + 0.5) * W - 0.5, (0.5 - lat / np.pi) * H - 0.5], -1)


def equirect_to_direction(uv, height: int):
    """Pixel coordinates to unit panorama-frame directions (the inverse of :func:`direction_to_equirect`).

    Args:
        uv: ``(..., 2)`` pixel coordinates ``(u, v)``, numpy or torch.
        height: panorama height ``H``.

    Returns:
        ``(..., 3)`` unit directions, the same kind as ``uv``.

    Examples:
        >>> round(float(equirect_to_direction(np.array([3.5, 1.5]), 4)[2]), 4)  # the centre looks forward
        1.0
        >>> [round(float(v), 4) for v in equirect_to_direction(np.array([5.5, 0.5]), 4)]
        [0.7071, -0.7071, 0.0]
        >>> uv = torch.tensor([2.0, 0.75])
        >>> [round(float(v), 4) for v in direction_to_equirect(equirect_to_direction(uv, 4), 4)]
        [2.0, 0.75]
    """
    W, H = 2 * height, height
    lib = torch if _is_torch(uv) else np
    lon = ((uv[..., 0] + 0.5) / W - 0.5) * (2 * math.pi)
    lat = (0.5 - (uv[..., 1] + 0.5) / H) * math.pi
    c = lib.cos(lat)
    return lib.stack([c * lib.sin(lon), -lib.sin(lat), c * lib.cos(lon)], -1)


def equirect_grid(height: int) -> np.ndarray:
    """Pixel-centre coordinates of a panorama.

    Args:
        height: panorama height ``H``.

    Returns:
        ``(H, 2H, 2)`` float64 coordinates, order ``(u, v)``.

    Examples:
        >>> g = equirect_grid(2)
        >>> g.shape, g[1, 3].tolist()
        ((2, 4, 2), [3.0, 1.0])
    """
    u, v = np.meshgrid(np.arange(2 * height, dtype=np.float64), np.arange(height, dtype=np.float64))
    return np.stack([u, v], -1)


@dataclass(frozen=True, eq=False)
class PanoramaCamera:
    """An equirectangular camera at ``center`` (camera frame) with orientation ``rotation``.

    ``rotation`` is a 3x3 matrix whose columns are the panorama frame's x (right), y (down) and
    z (forward) axes in camera coordinates, so ``d_cam = rotation @ d_pano``.

    Raises:
        ValueError: ``rotation`` is not a proper rotation or ``height`` is not an integer >= 2.

    Examples:
        A level panorama at ``(0, 0, 3)`` looking along the camera's z axis, up being the camera's -y:

        >>> pano = PanoramaCamera.level((0.0, 0.0, 3.0), (0.0, -1.0, 0.0), (0.0, 0.0, 1.0), 4)
        >>> pano.shape, pano.project_points(np.array([0.0, 0.0, 5.0])).tolist()
        ((4, 8), [3.5, 1.5])
        >>> [round(float(v), 4) for v in pano.project_directions(np.array([0.0, -1.0, 0.0]))]  # up
        [3.5, -0.5]
        >>> round(float(np.abs(np.linalg.norm(pano.directions(), axis=-1) - 1).max()), 4)
        0.0
    """

    center: np.ndarray
    rotation: np.ndarray
    height: int

    def __post_init__(self) -> None:
        c = np.asarray(self.center, np.float64).reshape(3)
        R = np.asarray(self.rotation, np.float64).reshape(3, 3)
        if not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
            raise ValueError("PanoramaCamera.rotation must be a proper rotation matrix")
        if int(self.height) != self.height or self.height < 2:
            raise ValueError(f"panorama height must be an integer >= 2, got {self.height!r}")
        object.__setattr__(self, "center", c)
        object.__setattr__(self, "rotation", R)
        object.__setattr__(self, "height", int(self.height))

    @property
    def width(self) -> int:
        """Panorama width, ``2 * height``."""
        return 2 * self.height

    @property
    def shape(self) -> tuple[int, int]:
        """``(height, width)``."""
        return (self.height, self.width)

    @classmethod
    def level(cls, center, up, forward, height: int) -> PanoramaCamera:
        """A gravity-aligned panorama: its top row looks along ``up``, its centre along ``forward``
        projected onto the horizontal plane (both in camera coordinates).

        Args:
            center: ``(3,)`` panorama centre (camera frame).
            up: ``(3,)`` up direction (any length > 0).
            forward: ``(3,)`` direction of the panorama's centre column; any horizontal direction
                when it is (nearly) parallel to ``up``.
            height: panorama height.

        Returns:
            The :class:`PanoramaCamera`.
        """
        up = np.asarray(up, np.float64)
        up = up / np.linalg.norm(up)
        fwd = np.asarray(forward, np.float64)
        fwd = fwd - (fwd @ up) * up
        if np.linalg.norm(fwd) < 1e-8:  # looking straight up or down: any horizontal direction
            fwd = np.cross(up, [1.0, 0.0, 0.0])
            if np.linalg.norm(fwd) < 1e-8:
                fwd = np.cross(up, [0.0, 0.0, 1.0])
        fwd = fwd / np.linalg.norm(fwd)
        y = -up
        x = np.cross(y, fwd)
        return cls(center=center, rotation=np.stack([x, y, fwd], axis=1), height=height)

    def directions(self) -> np.ndarray:
        """Unit camera-frame directions of every panorama pixel centre, ``(H, 2H, 3)``."""
        return equirect_to_direction(equirect_grid(self.height), self.height) @ self.rotation.T

    def project_directions(self, d_cam: np.ndarray) -> np.ndarray:
        """Camera-frame directions ``(..., 3)`` to panorama pixel coordinates ``(..., 2)``."""
        return direction_to_equirect(np.asarray(d_cam, np.float64) @ self.rotation, self.height)

    def project_points(self, p_cam: np.ndarray) -> np.ndarray:
        """Camera-frame points ``(..., 3)`` to the panorama pixels that see them ``(..., 2)``."""
        return self.project_directions(np.asarray(p_cam, np.float64) - self.center)

    def to_dict(self) -> dict:
        """JSON-serialisable form (:meth:`from_dict` inverts it)."""
        return {"center": self.center.tolist(), "rotation": self.rotation.tolist(), "height": self.height}

    @classmethod
    def from_dict(cls, d: dict) -> PanoramaCamera:
        """The panorama of a :meth:`to_dict` result."""
        return cls(center=np.asarray(d["center"]), rotation=np.asarray(d["rotation"]), height=int(d["height"]))
