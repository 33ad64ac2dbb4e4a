"""Vectorised value noise and the small math helpers of the procedural textures."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["Noise", "smoothstep", "fract", "mix", "rot_y", "random_rotation"]


def smoothstep(e0: float, e1: float, x: np.ndarray) -> np.ndarray:
    """Hermite step from 0 at ``e0`` to 1 at ``e1`` (``e1 < e0`` gives a falling step).

    Args:
        e0: Edge where the result is 0.
        e1: Edge where the result is 1.
        x: Values to evaluate at.

    Returns:
        ``3t² - 2t³`` with ``t = clip((x - e0) / (e1 - e0), 0, 1)``.
    """
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def fract(x: np.ndarray) -> np.ndarray:
    """Returns the fractional part ``x - floor(x)``, in ``[0, 1)``."""
    return x - np.floor(x)


def mix(a, b, t: np.ndarray) -> np.ndarray:
    """Blends two colours linearly.

    Args:
        a: Colour at ``t = 0``, (3,) or (N, 3).
        b: Colour at ``t = 1``, (3,) or (N, 3).
        t: Weights, (N,).

    Returns:
        ``a + (b - a) t`` as float32 (N, 3).
    """
    a = np.asarray(a, np.float32)
    b = np.asarray(b, np.float32)
    t = np.asarray(t, np.float32)[:, None]
    return (a + (b - a) * t).astype(np.float32)


def rot_y(angle: float) -> np.ndarray:
    """Rotation about world y by ``angle`` radians; columns are the rotated x, y, z axes."""
    # Rotation.from_euler("y", angle) goes through a quaternion and differs in the last bit.
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A uniformly random 3-D rotation matrix (QR of a Gaussian matrix, determinant +1).

    Args:
        rng: Source of the nine normal variates it draws.

    Returns:
        A (3, 3) float64 rotation matrix.
    """
    # Rotation.random draws a quaternion (4 normals) instead, so it gives other matrices.
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q


class Noise:
    """Smooth 3-D value noise on a periodic (64³) random lattice, evaluated vectorised.

    ``noise(p)`` returns values in [0, 1]; ``fbm`` sums rotated octaves. ``cell(i, j, k)`` gives a
    random number in [0, 1) per integer lattice cell (for per-plank/per-tile variation).

    Args:
        rng: Draws the lattice values, then one rotation and one offset per octave.
        octaves: The most octaves :meth:`fbm` can sum.
    """

    P = 64

    def __init__(self, rng: np.random.Generator, octaves: int = 8):
        self.table = rng.random(self.P**3, dtype=np.float32)
        self.rot = [random_rotation(rng).astype(np.float32) for _ in range(octaves)]
        self.off = rng.uniform(0, self.P, size=(octaves, 3)).astype(np.float32)

    def noise(self, p: np.ndarray) -> np.ndarray:
        """Trilinearly interpolated (smoothstep-weighted) lattice noise.

        Args:
            p: Points, (N, 3).

        Returns:
            Noise values in [0, 1], float32 (N,).
        """
        p = np.asarray(p, np.float32)
        fl = np.floor(p)
        f = p - fl
        f = f * f * (3.0 - 2.0 * f)
        i = fl.astype(np.int32)
        m = self.P - 1
        x0 = (i[:, 0] & m) << 12
        x1 = ((i[:, 0] + 1) & m) << 12
        y0 = (i[:, 1] & m) << 6
        y1 = ((i[:, 1] + 1) & m) << 6
        z0 = i[:, 2] & m
        z1 = (i[:, 2] + 1) & m
        T = self.table
        fx, fy, fz = f[:, 0], f[:, 1], f[:, 2]
        xy00, xy01, xy10, xy11 = x0 + y0, x0 + y1, x1 + y0, x1 + y1
        a = T[xy00 + z0]
        a += (T[xy00 + z1] - a) * fz
        b = T[xy01 + z0]
        b += (T[xy01 + z1] - b) * fz
        c = T[xy10 + z0]
        c += (T[xy10 + z1] - c) * fz
        d = T[xy11 + z0]
        d += (T[xy11 + z1] - d) * fz
        a += (b - a) * fy
        c += (d - c) * fy
        a += (c - a) * fx
        return a

    def fbm(self, p: np.ndarray, freq, octaves: int = 3, gain: float = 0.5) -> np.ndarray:
        """Fractal sum of rotated noise layers, normalised to [0, 1].

        Args:
            p: Points, (N, 3).
            freq: Base frequency, a scalar or per axis (3,).
            octaves: Number of layers; each doubles the frequency.
            gain: Amplitude factor from one layer to the next.

        Returns:
            Float32 (N,).
        """
        p = np.asarray(p, np.float32) * np.asarray(freq, np.float32)
        total = np.zeros(len(p), np.float32)
        amp, norm, scale = 1.0, 0.0, 1.0
        for o in range(octaves):
            total += amp * self.noise((p * scale) @ self.rot[o] + self.off[o])
            norm += amp
            amp *= gain
            scale *= 2.0
        return total / norm

    def cell(self, i: np.ndarray, j: np.ndarray, k: int = 0) -> np.ndarray:
        """A random number in [0, 1) per integer cell ``(i, j, k)`` (arrays broadcast)."""
        m = self.P - 1
        idx = ((np.asarray(i, np.int64) & m) << 12) + ((np.asarray(j, np.int64) & m) << 6) + (k & m)
        return self.table[idx]
