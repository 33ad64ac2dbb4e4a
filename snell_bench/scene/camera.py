"""Pinhole camera.

Convention:
    - Frame: OpenCV. The camera sits at the origin, x points right, y down, z forward.
    - Pixel coordinates: x right, y down; *integer values are pixel centres* (the convention of
      OpenCV's and kornia's ``remap``). The image covers ``[-0.5, W - 0.5] x [-0.5, H - 0.5]``.
    - Depth: the z coordinate of a point (distance along the optical axis), not the ray length.
    - Arrays are numpy, float64 unless stated; directions are unit vectors.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["Camera"]


@dataclass(frozen=True, eq=False)
class Camera:
    """A pinhole camera with intrinsics ``K`` (pixels) and an image of ``height x width`` pixels.

    Example:
        >>> cam = Camera.from_fov(1280, 720, fov_x_deg=60.0)
        >>> cam.K[0, 2], cam.K[1, 2]          # the principal point is the image centre
        (639.5, 359.5)
    """

    K: np.ndarray
    width: int
    height: int

    def __post_init__(self) -> None:
        K = np.asarray(self.K, dtype=np.float64)
        if K.shape != (3, 3):
            raise ValueError(f"Camera.K must be a 3x3 matrix, got shape {K.shape}")
        if not np.all(np.isfinite(K)):
            raise ValueError(f"Camera.K must be finite, got {K.tolist()}")
        if K[0, 0] <= 0 or K[1, 1] <= 0:
            raise ValueError(f"Camera.K focal lengths must be > 0, got fx={K[0, 0]}, fy={K[1, 1]}")
        if not np.allclose(K[2], [0.0, 0.0, 1.0]):
            raise ValueError(f"Camera.K last row must be [0, 0, 1], got {K[2].tolist()}")
        for name in ("width", "height"):
            v = getattr(self, name)
            if int(v) != v or v < 1:
                raise ValueError(f"Camera.{name} must be a positive integer, got {v!r}")
        K.setflags(write=False)
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_fov(cls, width: int, height: int, fov_x_deg: float) -> Camera:
        """Square pixels, principal point at the image centre, horizontal field of view in degrees.

        The field of view spans the full image width (pixel edges at -0.5 and W - 0.5).
        """
        if not (0.0 < float(fov_x_deg) < 180.0):
            raise ValueError(f"fov_x_deg must be in (0, 180), got {fov_x_deg}")
        f = 0.5 * width / math.tan(math.radians(fov_x_deg) / 2.0)
        K = np.array([[f, 0.0, (width - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0.0, 0.0, 1.0]])
        return cls(K=K, width=width, height=height)

    @property
    def shape(self) -> tuple[int, int]:
        """``(height, width)``."""
        return (self.height, self.width)

    @property
    def fov_x_deg(self) -> float:
        return math.degrees(2.0 * math.atan(0.5 * self.width / self.K[0, 0]))

    def scaled(self, factor: float) -> Camera:
        """The same camera at ``factor`` times the resolution (pixel-centre convention kept)."""
        w, h = max(1, round(self.width * factor)), max(1, round(self.height * factor))
        sx, sy = w / self.width, h / self.height
        K = self.K.copy()
        K[0, 0] *= sx
        K[1, 1] *= sy
        K[0, 2] = (K[0, 2] + 0.5) * sx - 0.5
        K[1, 2] = (K[1, 2] + 0.5) * sy - 0.5
        return Camera(K=K, width=w, height=h)

    # ------------------------------------------------------------------ rays and projection
    def pixel_grid(self) -> np.ndarray:
        """Pixel-centre coordinates, shape ``(H, W, 2)``, order ``(x, y)``."""
        x, y = np.meshgrid(np.arange(self.width, dtype=np.float64), np.arange(self.height, dtype=np.float64))
        return np.stack([x, y], axis=-1)

    def pixel_rays(self, pixels: np.ndarray | None = None, normalize: bool = True) -> np.ndarray:
        """Ray directions through pixel coordinates ``(..., 2)`` (default: every pixel centre).

        Returns ``(..., 3)``; unit length if ``normalize`` else with z = 1.
        """
        if pixels is None:
            pixels = self.pixel_grid()
        pixels = np.asarray(pixels, dtype=np.float64)
        Kinv = np.linalg.inv(self.K)
        d = pixels[..., 0:1] * Kinv[:, 0] + pixels[..., 1:2] * Kinv[:, 1] + Kinv[:, 2]
        if normalize:
            d = d / np.linalg.norm(d, axis=-1, keepdims=True)
        return d

    def unproject(self, depth: np.ndarray) -> np.ndarray:
        """Camera-frame points ``(H, W, 3)`` of a z-depth map ``(H, W)`` at pixel centres."""
        depth = np.asarray(depth, dtype=np.float64)
        if depth.shape != self.shape:
            raise ValueError(
                f"depth has shape {depth.shape} but the camera is {self.height}x{self.width}; "
                "pass a depth map of the camera's (height, width)"
            )
        return self.pixel_rays(normalize=False) * depth[..., None]

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project camera-frame points ``(..., 3)``.

        Returns ``(pixels (..., 2), z (...))``. Pixels of points with z <= 0 are NaN.
        """
        points = np.asarray(points, dtype=np.float64)
        z = points[..., 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uvw = points @ self.K.T
            pix = uvw[..., :2] / uvw[..., 2:3]
        pix = np.where((z > 0)[..., None], pix, np.nan)
        return pix, z

    def in_view(self, pixels: np.ndarray) -> np.ndarray:
        """Whether pixel coordinates ``(..., 2)`` fall inside the image area (NaN -> False)."""
        x, y = pixels[..., 0], pixels[..., 1]
        with np.errstate(invalid="ignore"):
            return (x >= -0.5) & (x <= self.width - 0.5) & (y >= -0.5) & (y <= self.height - 0.5)

    # ------------------------------------------------------------------ serialisation
    def to_dict(self) -> dict:
        return {"K": self.K.tolist(), "width": self.width, "height": self.height}

    @classmethod
    def from_dict(cls, d: dict) -> Camera:
        return cls(K=np.asarray(d["K"], dtype=np.float64), width=int(d["width"]), height=int(d["height"]))

    def __eq__(self, other: object) -> bool:
        return (
            isinstance(other, Camera)
            and self.width == other.width
            and self.height == other.height
            and np.array_equal(self.K, other.K)
        )

    def __hash__(self) -> int:
        return hash((self.width, self.height, self.K.tobytes()))

    def __repr__(self) -> str:
        return (
            f"Camera(width={self.width}, height={self.height}, fx={self.K[0, 0]:.3f}, fy={self.K[1, 1]:.3f}, "
            f"cx={self.K[0, 2]:.3f}, cy={self.K[1, 2]:.3f})"
        )
