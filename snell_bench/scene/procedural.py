"""Procedural scenes: parametric, textured 3-D scenes with exactly known geometry.

A :class:`ProceduralScene` stands in for "text-to-image model + monocular depth": it renders an
object-free image I⁻ of a scene, its *exact* depth and intrinsics, and 360° panoramas from any
point, all from one radiance field, :meth:`ProceduralScene.radiance`.  A scene is identified by
its ``kind`` (one of :data:`SCENE_KINDS`) and an integer ``seed``; the same pair always gives
bit-identical renders.

Conventions
-----------
- **Frame.** Every input and output is in the *camera frame* of the scene's perspective camera
  (OpenCV: camera at the origin, x right, y down, z forward; see :mod:`snell_bench.scene.camera`).
  Each scene is built in a world frame (y up, metres) and transformed into the camera frame once
  at construction.  World up expressed in the camera frame is :attr:`ProceduralScene.up`; it is
  not exactly ``(0, -1, 0)`` because the camera is pitched down.
- **Units.** Metres.  Ray parameters ``t`` are Euclidean distances along unit directions; depth is
  the camera-frame z coordinate at pixel centres.
- **Colour.** :meth:`~ProceduralScene.radiance` returns *linear* RGB radiance, scaled so that lit
  diffuse surfaces lie in ``[0, 1]`` (emitters such as the sun disc may exceed 1).  Images returned
  by :meth:`~ProceduralScene.render` and :meth:`~ProceduralScene.render_panorama` are the radiance
  clipped to ``[0, 1]`` (after averaging supersamples in linear space) and encoded with the
  standard sRGB transfer function (:func:`srgb_encode`), float32 in ``[0, 1]``.
- **Shading** is view-independent: a 3-D point has the same radiance from every viewpoint.
  Diffuse albedo (procedural, 3-D textures in world or object-local coordinates) times
  ``ambient + key light · max(0, n·l) · visibility``, with hard shadows from shadow rays, plus
  emissive surfaces (sky dome, windows, lamps) whose radiance is their texture.
- **Closure.** Each scene is closed (a room with a ceiling, or a 2 km sky dome), so every ray cast
  from a point inside the scene hits something and depth is finite everywhere.

All ray casting goes through one :class:`open3d.t.geometry.RaycastingScene` per scene (built
lazily on first use).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np
import trimesh

from snell_bench.imaging.color import linear_to_srgb, srgb_to_linear
from snell_bench.imaging.equirect import PanoramaCamera, equirect_grid, equirect_to_direction
from snell_bench.scene.camera import Camera

__all__ = [
    "SCENE_KINDS",
    "SceneRender",
    "ProceduralScene",
    "srgb_encode",
    "srgb_decode",
]

SCENE_KINDS = ("room", "outdoor", "kitchen")

_CHUNK = 1 << 19  # rays per ray-casting batch (bounds memory)


# ============================================================================ colour
def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """Linear RGB -> sRGB float32 (:func:`snell_bench.imaging.color.linear_to_srgb`)."""
    return linear_to_srgb(np.asarray(linear, dtype=np.float32)).astype(np.float32)


def srgb_decode(srgb: np.ndarray) -> np.ndarray:
    """sRGB -> linear RGB float32 (:func:`snell_bench.imaging.color.srgb_to_linear`)."""
    return srgb_to_linear(np.asarray(srgb, dtype=np.float32)).astype(np.float32)


def _lin(*rgb: float) -> np.ndarray:
    """An sRGB colour given as floats in [0, 1] -> linear float32 (3,)."""
    return srgb_decode(np.array(rgb, dtype=np.float32))


def _hsv(h: float, s: float, v: float) -> np.ndarray:
    """HSV (h in turns) -> linear RGB (3,)."""
    h = (h % 1.0) * 6.0
    i = int(h)
    f = h - i
    p, q, t = v * (1 - s), v * (1 - s * f), v * (1 - s * (1 - f))
    rgb = [(v, t, p), (q, v, p), (p, v, t), (p, q, v), (t, p, v), (v, p, q)][i % 6]
    return _lin(*rgb)


# ============================================================================ small helpers
def _smoothstep(e0: float, e1: float, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _fract(x: np.ndarray) -> np.ndarray:
    return x - np.floor(x)


def _mix(a, b, t: np.ndarray) -> np.ndarray:
    """Blend colours ``a``, ``b`` ((3,) or (N,3)) with weights ``t`` (N,) -> (N,3) float32."""
    a = np.asarray(a, np.float32)
    b = np.asarray(b, np.float32)
    t = np.asarray(t, np.float32)[:, None]
    return (a + (b - a) * t).astype(np.float32)


def _rot_y(angle: float) -> np.ndarray:
    """Rotation about world y; columns are the rotated x, y, z axes."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q


class _Noise:
    """Smooth 3-D value noise on a periodic (64³) random lattice, evaluated vectorised.

    ``noise(p)`` returns values in [0, 1]; ``fbm`` sums rotated octaves. ``cell(i)`` gives a
    random number in [0, 1) per integer lattice cell (for per-plank/per-tile variation).
    """

    P = 64

    def __init__(self, rng: np.random.Generator, octaves: int = 8):
        self.table = rng.random(self.P**3, dtype=np.float32)
        self.rot = [_random_rotation(rng).astype(np.float32) for _ in range(octaves)]
        self.off = rng.uniform(0, self.P, size=(octaves, 3)).astype(np.float32)

    def noise(self, p: np.ndarray) -> np.ndarray:
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
        """Fractal sum of ``octaves`` rotated noise layers; ``freq`` scalar or per-axis (3,)."""
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
        m = self.P - 1
        idx = ((np.asarray(i, np.int64) & m) << 12) + ((np.asarray(j, np.int64) & m) << 6) + (k & m)
        return self.table[idx]


# ============================================================================ materials
@dataclass
class _Material:
    """A procedural material. ``albedo(p, n)`` gets object-local points/normals (M,3) and returns
    linear RGB (M,3): diffuse albedo, or emitted radiance when ``emissive``."""

    name: str
    albedo: Callable[[np.ndarray, np.ndarray], np.ndarray]
    emissive: bool = False
    casts_shadow: bool = True
    origin: np.ndarray | None = None  # local frame origin (world)
    axes: np.ndarray | None = None  # columns: local axes in world coordinates


def _solid(color, noise: _Noise, amount: float = 0.08, freq: float = 6.0):
    color = np.asarray(color, np.float32)

    def f(p, n):
        v = noise.fbm(p, freq, 2)
        return color[None, :] * (1.0 - amount + 2.0 * amount * v)[:, None]

    return f


def _wood(light, dark, noise: _Noise, ring_freq: float = 9.0, grain: float = 1.0):
    """Wood with growth rings around an axis parallel to local x, below the local origin."""

    def f(p, n):
        y = p[:, 1] + 0.35 + 0.05 * np.sin(p[:, 0] * 1.7)
        warp = noise.fbm(p, (0.5, 2.0, 2.0), 3)
        r = np.sqrt(y**2 + p[:, 2] ** 2) * ring_freq + 3.0 * warp
        rings = _fract(r)
        rings = _smoothstep(0.0, 0.75, rings) * _smoothstep(1.0, 0.85, rings)
        fine = noise.fbm(p, (2.0, 60.0, 60.0), 2)
        t = np.clip(0.6 * rings + grain * 0.7 * (fine - 0.5) + 0.15 * (warp - 0.5), 0, 1)
        return _mix(light, dark, t)

    return f


def _planks(light, dark, noise: _Noise, width: float, length: float, seam):
    """Floor planks running along local x, ``width`` across (local z)."""
    seam = np.asarray(seam, np.float32)

    def f(p, n):
        row = np.floor(p[:, 2] / width)
        xs = p[:, 0] + noise.cell(row.astype(np.int64), 7) * length
        col = np.floor(xs / length)
        tone = noise.cell(row.astype(np.int64), col.astype(np.int64), 3)
        q = np.stack([xs - col * length, p[:, 1], p[:, 2] - row * width - 0.5 * width + 0.4 * tone], 1)
        r = np.sqrt(q[:, 1] ** 2 + (q[:, 2] + 0.6) ** 2) * 14.0 + 2.0 * noise.fbm(q * 1.0 + tone[:, None] * 9, (0.6, 3, 3), 2)
        rings = _fract(r)
        rings = _smoothstep(0.0, 0.6, rings) * _smoothstep(1.0, 0.75, rings)
        fine = noise.fbm(q + tone[:, None] * 17, (1.2, 25.0, 40.0), 2)
        c = _mix(light, dark, np.clip(0.3 * tone + 0.35 * rings + 0.35 * fine, 0, 1))
        u = _fract(p[:, 2] / width)
        v = _fract(xs / length)
        edge = np.minimum(np.minimum(u, 1 - u) * width, np.minimum(v, 1 - v) * length)
        s = _smoothstep(0.0015, 0.004, edge)
        return _mix(seam, c, s)

    return f


def _rug(colors, noise: _Noise, half_x: float, half_z: float, style: int):
    """Rug pattern on a rug centred at the local origin (local x, z span the rug)."""
    c0, c1, c2 = [np.asarray(c, np.float32) for c in colors]

    def f(p, n):
        ax, az = np.abs(p[:, 0]), np.abs(p[:, 2])
        bx, bz = half_x - ax, half_z - az
        border = np.minimum(bx, bz)
        if style == 0:  # stripes
            v = _fract(p[:, 0] * 4.0)
            inner = np.where(v < 0.5, 0.0, 1.0)
        elif style == 1:  # checker
            inner = ((np.floor(p[:, 0] * 5.0) + np.floor(p[:, 2] * 5.0)) % 2).astype(np.float32)
        else:  # diamonds
            inner = (_fract((ax + az) * 4.0) < 0.5).astype(np.float32)
        col = _mix(c0, c1, inner)
        band = (border < 0.12).astype(np.float32) * (border > 0.04)
        col = _mix(col, c2, band)
        fib = noise.fbm(p, 60.0, 2)
        return col * (0.82 + 0.36 * fib)[:, None]

    return f


def _wallpaper(base, stripe, noise: _Noise, period: float, width: float):
    """Vertical stripes along ``u = x + z`` (walls are axis-aligned)."""

    def f(p, n):
        u = p[:, 0] + p[:, 2]
        s = _fract(u / period)
        m = _smoothstep(0.0, 0.01, s) * _smoothstep(width + 0.01, width, s)
        thin = np.abs(s - (width + 1.0) / 2.0) < 0.015
        c = _mix(base, stripe, np.maximum(m, 0.7 * thin))
        return c * (0.92 + 0.16 * noise.fbm(p, 8.0, 2))[:, None]

    return f


def _tiles(c0, c1, grout, noise: _Noise, size: float, checker: bool, axes=(0, 2)):
    """Square tiles in the local (axes[0], axes[1]) plane with grout lines."""
    grout = np.asarray(grout, np.float32)

    def f(p, n):
        a, b = p[:, axes[0]] / size, p[:, axes[1]] / size
        ia, ib = np.floor(a), np.floor(b)
        if checker:
            t = ((ia + ib) % 2).astype(np.float32)
        else:
            t = 0.25 * noise.cell(ia.astype(np.int64), ib.astype(np.int64), 5)
        col = _mix(c0, c1, t) * (0.9 + 0.2 * noise.fbm(p, 3.0, 2))[:, None]
        fa, fb = a - ia, b - ib
        edge = np.minimum(np.minimum(fa, 1 - fa), np.minimum(fb, 1 - fb)) * size
        return _mix(grout, col, _smoothstep(0.002, 0.004, edge))

    return f


def _marble(base, vein, noise: _Noise):
    """White marble with thin, turbulent dark veins."""

    def f(p, n):
        w = noise.fbm(p, 1.2, 5)
        ph = (p[:, 0] * 1.1 + p[:, 2] * 0.7) * 5.0 + 9.0 * w
        v = np.abs(np.sin(ph))
        thick = 0.04 + 0.1 * noise.fbm(p, 2.0, 2)
        vm = 1.0 - _smoothstep(0.0, 1.0, v / thick)
        w2 = noise.fbm(p + 13.0, 3.0, 3)
        v2 = 1.0 - _smoothstep(0.0, 0.03, np.abs(np.sin((p[:, 0] * 0.6 - p[:, 2]) * 7.0 + 7.0 * w2)))
        t = np.clip(0.85 * vm + 0.4 * v2, 0, 1)
        c = _mix(base, vein, t)
        return c * (0.94 + 0.1 * noise.fbm(p, 6.0, 2))[:, None]

    return f


def _stone(light, dark, noise: _Noise, freq: float = 2.0):
    def f(p, n):
        a = noise.fbm(p, freq, 4)
        s = noise.noise(p * 40.0)
        return _mix(dark, light, np.clip(1.6 * (a - 0.5) + 0.5 + 0.25 * (s - 0.5), 0, 1))

    return f


def _cabinet(paint, noise: _Noise, door: float, groove):
    """Painted cabinet fronts: vertical grooves every ``door`` metres along u = x + z."""
    paint = np.asarray(paint, np.float32)
    groove = np.asarray(groove, np.float32)

    def f(p, n):
        u = _fract((p[:, 0] + p[:, 2]) / door)
        e = np.minimum(u, 1 - u) * door
        c = _mix(groove, paint, _smoothstep(0.003, 0.006, e))
        return c * (0.95 + 0.1 * noise.fbm(p, 5.0, 2))[:, None]

    return f


def _painting(rng: np.random.Generator, noise: _Noise, w: float, h: float):
    """A colourful canvas; local x in [0, w] (right), y in [0, h] (up)."""
    style = int(rng.integers(4))
    hue0 = rng.random()
    pal = np.stack([_hsv(hue0 + rng.uniform(-0.35, 0.35), rng.uniform(0.45, 0.95), rng.uniform(0.45, 0.95)) for _ in range(5)])
    params = rng.random(64)

    def f(p, n):
        u, v = np.clip(p[:, 0] / w, 0, 1), np.clip(p[:, 1] / h, 0, 1)
        if style == 0:  # interfering waves, palette-mapped
            s = np.zeros_like(u)
            for k in range(4):
                a, b, c = (params[3 * k : 3 * k + 3] - 0.5) * np.array([18, 18, 6])
                s += np.sin(a * u + b * v + c)
            t = np.clip((s + 4) / 8 * 4, 0, 3.999)
            i = np.floor(t).astype(np.int64)
            col = _mix(pal[i], pal[i + 1], _smoothstep(0.3, 0.7, t - i))
        elif style == 1:  # rectangles with dark lines
            cu = np.sort(params[:3])
            cv = np.sort(params[3:6])
            iu = np.searchsorted(cu, u)
            iv = np.searchsorted(cv, v)
            idx = (iu * 3 + iv * 2 + int(params[6] * 5)) % 5
            col = pal[idx].copy()
            du = np.min(np.abs(u[:, None] - cu[None]), 1) * w
            dv = np.min(np.abs(v[:, None] - cv[None]), 1) * h
            line = np.minimum(du, dv) < 0.008
            col[line] = 0.02
        elif style == 2:  # landscape: sky, sun, layered hills
            col = _mix(pal[0] * 0.4 + 0.6, pal[1], v)
            sun = (u - 0.25 - 0.5 * params[0]) ** 2 * (w / h) ** 2 + (v - 0.7 - 0.2 * params[1]) ** 2 < 0.01
            col[sun] = _lin(1.0, 0.9, 0.5)
            for k in range(3):
                hk = 0.55 - 0.15 * k + 0.08 * np.sin(u * (4 + 6 * params[10 + k]) + 6 * params[20 + k])
                col[v < hk] = pal[2 + k] * (0.9 - 0.15 * k)
        else:  # circles on a background
            col = np.broadcast_to(pal[0], (len(u), 3)).copy()
            for k in range(7):
                cx, cy, r = params[30 + 3 * k], params[31 + 3 * k], 0.08 + 0.2 * params[32 + 3 * k]
                inside = (u - cx) ** 2 * (w / h) ** 2 + (v - cy) ** 2 < r * r
                col[inside] = pal[1 + k % 4]
        brush = 0.9 + 0.2 * noise.fbm(p, (60.0, 15.0, 15.0), 2)
        return (col * brush[:, None]).astype(np.float32)

    return f


# ============================================================================ geometry builder
class _Builder:
    """Accumulates triangles (world frame) with per-vertex normals, per-face material and tint."""

    def __init__(self) -> None:
        self.V: list[np.ndarray] = []
        self.N: list[np.ndarray] = []
        self.F: list[np.ndarray] = []
        self.M: list[np.ndarray] = []
        self.T: list[np.ndarray] = []
        self.nv = 0
        self.materials: list[_Material] = []
        self._mat_index: dict[str, int] = {}

    def material(self, mat: _Material) -> int:
        if mat.name in self._mat_index:
            return self._mat_index[mat.name]
        self._mat_index[mat.name] = len(self.materials)
        self.materials.append(mat)
        return self._mat_index[mat.name]

    def add(self, V, F, N, mat: int, tint=(1.0, 1.0, 1.0)) -> None:
        V = np.asarray(V, np.float64).reshape(-1, 3)
        N = np.asarray(N, np.float64).reshape(-1, 3)
        N = N / np.maximum(np.linalg.norm(N, axis=1, keepdims=True), 1e-12)
        F = np.asarray(F, np.int64).reshape(-1, 3)
        self.V.append(V)
        self.N.append(N)
        self.F.append(F + self.nv)
        self.M.append(np.full(len(F), mat, np.int32))
        self.T.append(np.tile(np.asarray(tint, np.float32), (len(F), 1)))
        self.nv += len(V)

    # -------------------------------------------------------------- primitives
    def box(self, center, size, mat: int, yaw: float = 0.0, tint=(1.0, 1.0, 1.0)) -> None:
        """Axis-aligned (after a yaw about world y) box with flat faces."""
        c = np.asarray(center, np.float64)
        h = 0.5 * np.asarray(size, np.float64)
        R = _rot_y(yaw)
        V, N, F = [], [], []
        for axis in range(3):
            for sign in (-1.0, 1.0):
                n = np.zeros(3)
                n[axis] = sign
                a, b = [(axis + 1) % 3, (axis + 2) % 3]
                quad = []
                for sa, sb in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                    q = np.zeros(3)
                    q[axis] = sign * h[axis]
                    q[a] = sa * h[a]
                    q[b] = sb * h[b]
                    quad.append(q)
                base = len(V)
                V.extend(quad)
                N.extend([n] * 4)
                F.extend([[base, base + 1, base + 2], [base, base + 2, base + 3]])
        V = np.array(V) @ R.T + c
        N = np.array(N) @ R.T
        self.add(V, F, N, mat, tint)

    def quad(self, p0, p1, p2, p3, mat: int, tint=(1.0, 1.0, 1.0)) -> None:
        V = np.array([p0, p1, p2, p3], np.float64)
        n = np.cross(V[1] - V[0], V[2] - V[0])
        self.add(V, [[0, 1, 2], [0, 2, 3]], np.tile(n, (4, 1)), mat, tint)

    def grid(self, P: np.ndarray, mat: int, normals: np.ndarray | None = None, wrap: bool = False, tint=(1, 1, 1)) -> None:
        """A surface from a (rows, cols, 3) point grid (``wrap``: close the column direction)."""
        r, c = P.shape[:2]
        idx = np.arange(r * c).reshape(r, c)
        if wrap:
            idx = np.concatenate([idx, idx[:, :1]], 1)
        a, b = idx[:-1, :-1], idx[:-1, 1:]
        d, e = idx[1:, :-1], idx[1:, 1:]
        F = np.concatenate([np.stack([a, d, e], -1).reshape(-1, 3), np.stack([a, e, b], -1).reshape(-1, 3)])
        V = P.reshape(-1, 3)
        if normals is None:
            normals = trimesh.Trimesh(V, F, process=False).vertex_normals
        self.add(V, F, normals.reshape(-1, 3), mat, tint)

    def sphere(self, center, radii, mat: int, n_lat: int = 16, n_lon: int = 32, tint=(1, 1, 1)) -> None:
        c = np.asarray(center, np.float64)
        r = np.broadcast_to(np.asarray(radii, np.float64), (3,))
        th = np.linspace(0, np.pi, n_lat + 1)
        ph = np.linspace(0, 2 * np.pi, n_lon, endpoint=False)
        th, ph = np.meshgrid(th, ph, indexing="ij")
        u = np.stack([np.sin(th) * np.cos(ph), np.cos(th), np.sin(th) * np.sin(ph)], -1)
        self.grid(u * r + c, mat, normals=u / r, wrap=True, tint=tint)

    def rock(self, center, radii, mat: int, rng: np.random.Generator, noise: _Noise, tint=(1, 1, 1)) -> None:
        ico = trimesh.creation.icosphere(subdivisions=3)
        v = np.asarray(ico.vertices)
        off = rng.uniform(-50, 50, 3)
        d = noise.fbm((v * 1.3 + off).astype(np.float32), 1.0, 3)
        v = v * (0.75 + 0.5 * d)[:, None] * np.asarray(radii) @ _rot_y(rng.uniform(0, 2 * np.pi)).T
        v = v + np.asarray(center)
        m = trimesh.Trimesh(v, ico.faces, process=False)
        self.add(v, ico.faces, m.vertex_normals, mat, tint)

    def cylinder(self, base, radius: float, height: float, mat: int, n: int = 32, caps: bool = True,
                 tint=(1, 1, 1), top_radius: float | None = None) -> None:
        b = np.asarray(base, np.float64)
        rt = radius if top_radius is None else top_radius
        ph = np.linspace(0, 2 * np.pi, n, endpoint=False)
        ring = np.stack([np.cos(ph), np.zeros(n), np.sin(ph)], -1)
        P = np.stack([ring * radius + b, ring * rt + b + [0, height, 0]])
        slope = (radius - rt) / height
        Nr = ring + np.array([0, slope, 0])
        self.grid(P, mat, normals=np.stack([Nr, Nr]), wrap=True, tint=tint)
        if caps:
            for y, r, s in ((0.0, radius, -1.0), (height, rt, 1.0)):
                V = np.concatenate([[b + [0, y, 0]], ring * r + b + [0, y, 0]])
                F = [[0, 1 + (i + 1) % n, 1 + i] for i in range(n)]
                self.add(V, F, np.tile([0, s, 0], (n + 1, 1)), mat, tint)

    def finish(self):
        return (
            np.concatenate(self.V),
            np.concatenate(self.N),
            np.concatenate(self.F),
            np.concatenate(self.M),
            np.concatenate(self.T),
        )


# ============================================================================ the scene
@dataclass
class SceneRender:
    """A perspective render: sRGB image (H, W, 3) float32 in [0, 1], exact z-depth (H, W) float32
    at pixel centres (finite, > 0), and the camera."""

    image: np.ndarray
    depth: np.ndarray
    camera: Camera


@dataclass
class _Light:
    kind: str  # "point" or "directional"
    vector: np.ndarray  # camera frame: position (point) or unit direction towards the light
    color: np.ndarray  # linear RGB intensity (point: at 1 m)
    ambient_sky: np.ndarray  # hemispherical ambient from above
    ambient_ground: np.ndarray  # ... and from below


class ProceduralScene:
    """A parametric textured 3-D scene with exactly known geometry, in its camera's frame.

    Parameters
    ----------
    kind : one of :data:`SCENE_KINDS` — ``"room"`` (living room with a wooden table),
        ``"outdoor"`` (stone table on open ground, mountains, sky) or ``"kitchen"`` (marble island).
    seed : non-negative int; selects colours, layout, light and camera pose.

    Attributes
    ----------
    up : (3,) unit world-up direction in the camera frame.
    support_point : (3,) camera-frame point on the (horizontal) top of the supporting surface — the
        table / stone table / island — near the image centre column, lower half, where an object
        can stand.  Nothing else occupies the surface within ~0.25 m of it.
    support_normal : (3,) equal to ``up``.
    fov_x_deg : horizontal field of view of :meth:`camera`.
    camera_height : height of the camera above the floor / ground (m).

    All methods take and return camera-frame quantities (OpenCV axes, metres).
    """

    def __init__(self, kind: str = "room", seed: int = 0):
        if kind not in SCENE_KINDS:
            raise ValueError(f"unknown scene kind {kind!r}; valid kinds are {', '.join(map(repr, SCENE_KINDS))}")
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
            raise TypeError(f"seed must be an int, got {type(seed).__name__} {seed!r}")
        if seed < 0:
            raise ValueError(f"seed must be >= 0, got {seed}")
        self.kind = kind
        self.seed = int(seed)
        rng = np.random.default_rng(self.seed)
        self._noise = _Noise(rng)
        self._b = _Builder()
        self.fov_x_deg = float(rng.uniform(58.0, 68.0))
        if kind == "outdoor":
            world = self._build_outdoor(rng)
        else:
            world = self._build_room(rng, kitchen=(kind == "kitchen"))
        self._finalize(world)
        del self._b
        self._rc = None  # the Open3D RaycastingScene, built on first use

    # ------------------------------------------------------------------ public API
    def camera(self, width: int = 1280, height: int = 720) -> Camera:
        """The scene's pinhole camera at the given resolution (square pixels, centred principal point)."""
        return Camera.from_fov(width, height, self.fov_x_deg)

    def render(self, width: int = 1280, height: int = 720, supersample: int = 1) -> SceneRender:
        """Object-free image, exact z-depth and camera.

        ``supersample = s`` averages s×s stratified sub-pixel samples (linear space) for the image;
        depth is always cast through the pixel centres.
        """
        s = self._check_ss(supersample)
        cam = self.camera(width, height)
        d = cam.pixel_rays()  # (H, W, 3) unit
        origins = np.zeros(3)
        if s == 1:
            rad, t = self.radiance(origins, d.reshape(-1, 3))
            img = rad.reshape(height, width, 3)
        else:
            t = self._cast_t(np.zeros((1, 3)), d.reshape(-1, 3))
            grid = cam.pixel_grid()
            acc = np.zeros((height * width, 3), np.float64)
            for oy, ox in self._offsets(s):
                ds = cam.pixel_rays(grid + np.array([ox, oy]))
                acc += self.radiance(origins, ds.reshape(-1, 3))[0]
            img = (acc / (s * s)).reshape(height, width, 3)
        depth = (t.astype(np.float64) * d[..., 2].reshape(-1)).reshape(height, width).astype(np.float32)
        return SceneRender(image=srgb_encode(img), depth=depth, camera=cam)

    def render_panorama(self, center=(0.0, 0.0, 0.0), height: int = 1024, up=None, forward=(0.0, 0.0, 1.0),
                        supersample: int = 1) -> np.ndarray:
        """Equirectangular panorama ``(height, 2*height, 3)`` float32 sRGB from camera-frame ``center``.

        Oriented by ``PanoramaCamera.level(center, up or self.up, forward, height)``: its top row
        looks along ``up``, its centre column along ``forward`` made horizontal.
        """
        s = self._check_ss(supersample)
        pc = PanoramaCamera.level(np.asarray(center, np.float64), self.up if up is None else up, forward, height)
        if s == 1:
            rad = self.radiance(pc.center, pc.directions().reshape(-1, 3))[0]
        else:
            grid = equirect_grid(height)
            rad = np.zeros((height * 2 * height, 3), np.float64)
            for oy, ox in self._offsets(s):
                dirs = equirect_to_direction(grid + np.array([ox, oy]), height) @ pc.rotation.T
                rad += self.radiance(pc.center, dirs.reshape(-1, 3))[0]
            rad /= s * s
        return srgb_encode(rad.reshape(height, 2 * height, 3))

    def radiance(self, origins: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Linear-RGB radiance arriving along rays, and their hit distances.

        ``origins`` (N,3) or (3,) (broadcast), ``directions`` (N,3), camera frame; directions need
        not be unit (they are normalised). Returns ``(radiance (N,3) float32, t (N,) float32)`` with
        ``t`` the Euclidean distance to the first surface (``inf`` where nothing is hit; such rays
        get the scene's environment radiance).
        """
        d = np.asarray(directions, np.float64).reshape(-1, 3)
        o = np.asarray(origins, np.float64)
        o = np.broadcast_to(o.reshape(-1, 3) if o.ndim > 1 else o.reshape(1, 3), d.shape)
        n = len(d)
        norm = np.linalg.norm(d, axis=1, keepdims=True)
        if np.any(~np.isfinite(norm)) or np.any(norm <= 0):
            raise ValueError("directions must be finite and non-zero")
        d = d / norm
        rad = np.empty((n, 3), np.float32)
        t = np.empty(n, np.float32)
        for a in range(0, n, _CHUNK):
            b = min(n, a + _CHUNK)
            rad[a:b], t[a:b] = self._shade(o[a:b], d[a:b])
        return rad, t

    def mesh(self) -> trimesh.Trimesh:
        """All scene geometry in camera coordinates. ``metadata['face_material']`` holds each face's
        material index into ``metadata['material_names']``."""
        m = trimesh.Trimesh(vertices=self._V.copy(), faces=self._F.copy(), process=False)
        m.metadata["face_material"] = self._mat.copy()
        m.metadata["material_names"] = [mt.name for mt in self._materials]
        return m

    @property
    def material_names(self) -> list[str]:
        return [m.name for m in self._materials]

    def world_to_camera(self, p_world: np.ndarray) -> np.ndarray:
        """World-frame points (y up, metres) -> camera frame."""
        return (np.asarray(p_world, np.float64) - self._C) @ self._R

    def camera_to_world(self, p_cam: np.ndarray) -> np.ndarray:
        return np.asarray(p_cam, np.float64) @ self._R.T + self._C

    def __repr__(self) -> str:
        return f"ProceduralScene(kind={self.kind!r}, seed={self.seed})"

    # ------------------------------------------------------------------ internals
    @staticmethod
    def _check_ss(s) -> int:
        if int(s) != s or s < 1:
            raise ValueError(f"supersample must be a positive integer, got {s!r}")
        return int(s)

    @staticmethod
    def _offsets(s: int):
        c = (np.arange(s) + 0.5) / s - 0.5
        return [(oy, ox) for oy in c for ox in c]

    def _set_camera(self, position, target, pitch_jitter: float, table_top: float, table_dist: float,
                    offset: float = 0.55):
        """Camera at ``position`` heading towards ``target`` (horizontally); pitched so that the
        target appears ``offset`` of the half image height below the centre (16:9 reference)."""
        C = np.asarray(position, np.float64)
        to = np.asarray(target, np.float64) - C
        yaw = math.atan2(to[0], to[2])
        alpha = math.atan2(C[1] - table_top, table_dist)
        tan_half_v = math.tan(math.radians(self.fov_x_deg) / 2) * 9.0 / 16.0
        pitch = alpha - math.atan(offset * tan_half_v) + pitch_jitter
        pitch = float(np.clip(pitch, math.radians(10.0), math.radians(22.0)))
        return C, yaw, pitch

    def _finalize(self, world: dict) -> None:
        C, yaw, pitch = world["camera"]
        f = np.array([math.sin(yaw) * math.cos(pitch), -math.sin(pitch), math.cos(yaw) * math.cos(pitch)])
        down = np.array([0.0, -1.0, 0.0])
        down = down - (down @ f) * f
        down /= np.linalg.norm(down)
        right = np.cross(down, f)
        R = np.stack([right, down, f], axis=1)  # columns: camera axes in world
        self._R, self._C = R, C
        self.pitch_deg = math.degrees(pitch)
        self.camera_height = float(C[1] - world.get("floor", 0.0))
        V, N, F, M, T = self._b.finish()
        self._V = (V - C) @ R
        self._VN = (N @ R).astype(np.float32)
        self._F = F
        self._mat = M
        self._tint = T
        self._materials = self._b.materials
        tri = self._V[F]
        fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-30)
        vsum = self._VN[F].sum(1)
        fn *= np.where(np.sum(fn * vsum, 1) < 0, -1.0, 1.0)[:, None]  # agree with vertex normals
        self._FN = fn.astype(np.float32)
        self._emissive = np.array([m.emissive for m in self._materials])
        self._casts = np.array([m.casts_shadow for m in self._materials])
        # per-material world->local transforms
        self._local = []
        for m in self._materials:
            o = np.zeros(3) if m.origin is None else np.asarray(m.origin, np.float64)
            A = np.eye(3) if m.axes is None else np.asarray(m.axes, np.float64)
            self._local.append((o, A))
        self.up = (np.array([0.0, 1.0, 0.0]) @ R).astype(np.float64)
        self.up /= np.linalg.norm(self.up)
        self.support_normal = self.up.copy()
        self.support_point = self.world_to_camera(world["support"])
        L = world["light"]
        vec = self.world_to_camera(L["vector"]) if L["kind"] == "point" else np.asarray(L["vector"]) @ R
        self._light = _Light(L["kind"], vec, np.asarray(L["color"], np.float32),
                             np.asarray(L["ambient_sky"], np.float32), np.asarray(L["ambient_ground"], np.float32))
        self._env = world.get("env")
        self._falloff = float(L.get("falloff", 0.0))

    def _scene(self):
        if self._rc is None:
            import open3d as o3d

            rc = o3d.t.geometry.RaycastingScene()
            rc.add_triangles(
                o3d.core.Tensor(np.ascontiguousarray(self._V, dtype=np.float32)),
                o3d.core.Tensor(np.ascontiguousarray(self._F, dtype=np.uint32)),
            )
            self._rc = rc
        return self._rc

    def _cast(self, o: np.ndarray, d: np.ndarray):
        import open3d as o3d

        rays = np.empty((len(d), 6), np.float32)
        rays[:, :3] = o
        rays[:, 3:] = d
        out = self._scene().cast_rays(o3d.core.Tensor(rays))
        return out["t_hit"].numpy(), out["primitive_ids"].numpy().astype(np.int64), out["primitive_uvs"].numpy()

    def _cast_t(self, o: np.ndarray, d: np.ndarray) -> np.ndarray:
        t = np.empty(len(d), np.float32)
        o = np.broadcast_to(o, d.shape)
        for a in range(0, len(d), _CHUNK):
            b = min(len(d), a + _CHUNK)
            t[a:b] = self._cast(o[a:b], d[a:b] / np.linalg.norm(d[a:b], axis=1, keepdims=True))[0]
        return t

    def _shade(self, o: np.ndarray, d: np.ndarray):
        t, prim, uv = self._cast(o, d)
        n = len(d)
        rad = np.zeros((n, 3), np.float32)
        hit = np.isfinite(t)
        if self._env is not None and not hit.all():
            miss = ~hit
            rad[miss] = self._env(d[miss] @ self._R.T)
        if not hit.any():
            return rad, t
        hi = np.nonzero(hit)[0]
        tri = prim[hi]
        dh = d[hi]
        p = o[hi] + t[hi, None].astype(np.float64) * dh
        ng = self._FN[tri].astype(np.float64)
        u, v = uv[hi, 0:1], uv[hi, 1:2]
        vn = self._VN[self._F[tri]]
        ns = ((1.0 - u - v) * vn[:, 0] + u * vn[:, 1] + v * vn[:, 2]).astype(np.float64)
        ns /= np.maximum(np.linalg.norm(ns, axis=1, keepdims=True), 1e-12)
        flip = np.sum(ng * dh, 1) > 0
        ng[flip] *= -1
        ns[flip] *= -1
        mat = self._mat[tri]
        pw = p @ self._R.T + self._C
        nw = ns @ self._R.T
        col = np.empty((len(hi), 3), np.float32)
        for m in np.unique(mat):
            sel = np.nonzero(mat == m)[0]
            org, A = self._local[m]
            col[sel] = self._materials[m].albedo((pw[sel] - org) @ A, nw[sel] @ A)
        col *= self._tint[tri]
        emis = self._emissive[mat]
        lit = np.nonzero(~emis)[0]
        out = col.copy()
        if len(lit):
            L = self._light
            nl, pl, gl = ns[lit], p[lit], ng[lit]
            ny = nw[lit, 1:2].astype(np.float32)
            amb = L.ambient_sky * (0.5 + 0.5 * ny) + L.ambient_ground * (0.5 - 0.5 * ny)
            if L.kind == "point":
                tol = L.vector - pl
                dist = np.linalg.norm(tol, axis=1)
                ldir = tol / dist[:, None]
                fall = 1.0 / (dist**2 + self._falloff)
            else:
                ldir = np.broadcast_to(L.vector, pl.shape)
                dist = np.full(len(pl), np.inf)
                fall = np.ones(len(pl))
            cos = np.sum(nl * ldir, 1)
            cand = np.nonzero((cos > 0) & (np.sum(gl * ldir, 1) > -0.05))[0]
            direct = np.zeros(len(lit))
            if len(cand):
                eps = 1e-3 + 2e-6 * t[hi][lit][cand]
                so = pl[cand] + gl[cand] * eps[:, None]
                ts, ps, _ = self._cast(so, ldir[cand])
                blocked = np.isfinite(ts) & (ts < dist[cand] - 1e-3)
                bi = np.nonzero(blocked)[0]
                blocked[bi] = self._casts[self._mat[ps[bi]]]
                direct[cand] = np.where(blocked, 0.0, cos[cand] * fall[cand])
            shade = amb + L.color[None, :] * direct[:, None].astype(np.float32)
            out[lit] = col[lit] * shade
        rad[hi] = out
        return rad, t

    # ------------------------------------------------------------------ scene builders
    def _build_room(self, rng: np.random.Generator, kitchen: bool) -> dict:
        b, nz = self._b, self._noise
        W = rng.uniform(4.6, 5.6)
        D = rng.uniform(5.6, 6.6)
        Hc = rng.uniform(2.6, 2.9)
        x0, x1, z0, z1 = -W / 2, W / 2, 0.0, D

        # --- camera and support surface
        cam_h = rng.uniform(1.45, 1.55) if kitchen else rng.uniform(1.3, 1.42)
        cam = np.array([rng.uniform(-0.35, 0.35), cam_h, rng.uniform(0.5, 0.75)])
        heading = rng.uniform(-0.2, 0.2)
        tdist = rng.uniform(1.25, 1.5)
        top_h = 0.9 if kitchen else rng.uniform(0.72, 0.78)
        tc = cam + tdist * np.array([math.sin(heading), 0.0, math.cos(heading)])
        tc[1] = 0.0
        t_yaw = heading + rng.uniform(-0.18, 0.18)
        tlen = rng.uniform(1.3, 1.7) if kitchen else rng.uniform(1.2, 1.6)
        tdep = rng.uniform(0.85, 1.0) if kitchen else rng.uniform(0.75, 0.9)
        target = tc + np.array([0, top_h, 0]) + rng.uniform(-0.06, 0.06) * np.array([math.cos(heading), 0, -math.sin(heading)])
        camera = self._set_camera(cam, target, math.radians(rng.uniform(-1.5, 1.5)), top_h, tdist)
        Rt = _rot_y(t_yaw)
        tx, tz = Rt[:, 0], Rt[:, 2]

        # --- materials
        hue = rng.random()
        wall_base = _hsv(hue, rng.uniform(0.08, 0.3), rng.uniform(0.7, 0.88))
        wall_stripe = _hsv(hue + rng.uniform(-0.1, 0.1), rng.uniform(0.15, 0.4), rng.uniform(0.55, 0.75))
        m_wall = b.material(_Material("wallpaper", _wallpaper(wall_base, wall_stripe, nz, rng.uniform(0.18, 0.35), rng.uniform(0.3, 0.6))))
        m_ceil = b.material(_Material("ceiling", _solid(_lin(0.92, 0.91, 0.88), nz, 0.03)))
        wood_l = _hsv(rng.uniform(0.06, 0.1), rng.uniform(0.4, 0.6), rng.uniform(0.55, 0.8))
        wood_d = wood_l * rng.uniform(0.35, 0.55)
        plank_axis = _rot_y(0.0 if rng.random() < 0.5 else math.pi / 2)
        if kitchen:
            tc0 = _lin(*([rng.uniform(0.75, 0.9)] * 3))
            tc1 = _hsv(rng.random(), rng.uniform(0.1, 0.4), rng.uniform(0.25, 0.5))
            m_floor = b.material(_Material("floor_tiles", _tiles(tc0, tc1, _lin(0.4, 0.4, 0.38), nz, rng.uniform(0.3, 0.5), True)))
        else:
            m_floor = b.material(_Material("floor_planks", _planks(wood_l, wood_d, nz, rng.uniform(0.14, 0.22), rng.uniform(1.0, 1.6), wood_d * 0.4),
                                           axes=plank_axis))
        m_white = b.material(_Material("white_paint", _solid(_lin(0.9, 0.9, 0.88), nz, 0.03)))

        # --- shell (normals inward)
        fl = [[x0, 0, z0], [x1, 0, z0], [x1, 0, z1], [x0, 0, z1]]
        b.add(fl, [[0, 1, 2], [0, 2, 3]], [[0, 1, 0]] * 4, m_floor)
        ce = [[x0, Hc, z0], [x1, Hc, z0], [x1, Hc, z1], [x0, Hc, z1]]
        b.add(ce, [[0, 1, 2], [0, 2, 3]], [[0, -1, 0]] * 4, m_ceil)
        walls = [
            ([[x0, 0, z1], [x1, 0, z1], [x1, Hc, z1], [x0, Hc, z1]], [0, 0, -1]),
            ([[x0, 0, z0], [x1, 0, z0], [x1, Hc, z0], [x0, Hc, z0]], [0, 0, 1]),
            ([[x0, 0, z0], [x0, 0, z1], [x0, Hc, z1], [x0, Hc, z0]], [1, 0, 0]),
            ([[x1, 0, z0], [x1, 0, z1], [x1, Hc, z1], [x1, Hc, z0]], [-1, 0, 0]),
        ]
        for V, nrm in walls:
            b.add(V, [[0, 1, 2], [0, 2, 3]], [nrm] * 4, m_wall)
        bb = 0.1
        b.box([0, bb / 2, z1 - 0.01], [W, bb, 0.02], m_white)
        b.box([0, bb / 2, z0 + 0.01], [W, bb, 0.02], m_white)
        b.box([x0 + 0.01, bb / 2, D / 2], [0.02, bb, D], m_white)
        b.box([x1 - 0.01, bb / 2, D / 2], [0.02, bb, D], m_white)

        # --- the support: table or kitchen island
        top_c = tc + np.array([0, top_h, 0])
        if kitchen:
            m_marble = b.material(_Material("marble", _marble(_lin(0.93, 0.92, 0.9), _lin(0.35, 0.36, 0.4), nz), origin=top_c, axes=Rt))
            cab_col = _hsv(rng.random(), rng.uniform(0.1, 0.5), rng.uniform(0.3, 0.8))
            m_cab = b.material(_Material("cabinet", _cabinet(cab_col, nz, 0.5, cab_col * 0.4)))
            th = 0.04
            b.box(top_c - [0, th / 2, 0], [tlen, th, tdep], m_marble, t_yaw)
            b.box(tc + [0, (top_h - th) / 2, 0], [tlen - 0.12, top_h - th, tdep - 0.2], m_cab, t_yaw)
        else:
            m_table = b.material(_Material("table_wood", _wood(wood_l * 1.05, wood_d * 0.8, nz, rng.uniform(14, 24)), origin=top_c, axes=Rt))
            th = 0.035
            b.box(top_c - [0, th / 2, 0], [tlen, th, tdep], m_table, t_yaw)
            b.box(top_c - [0, th + 0.04, 0], [tlen - 0.1, 0.08, tdep - 0.1], m_table, t_yaw)
            for sx in (-1, 1):
                for sz in (-1, 1):
                    lc = tc + sx * (tlen / 2 - 0.07) * tx + sz * (tdep / 2 - 0.07) * tz
                    b.box(lc + [0, (top_h - th) / 2, 0], [0.055, top_h - th, 0.055], m_table, t_yaw)
            # rug under the table
            rcols = [_hsv(rng.random(), rng.uniform(0.3, 0.7), rng.uniform(0.3, 0.7)) for _ in range(3)]
            rhx, rhz = tlen / 2 + rng.uniform(0.5, 0.8), tdep / 2 + rng.uniform(0.5, 0.8)
            m_rug = b.material(_Material("rug", _rug(rcols, nz, rhx, rhz, int(rng.integers(3))), origin=tc, axes=Rt))
            b.box(tc + [0, 0.005, 0], [2 * rhx, 0.01, 2 * rhz], m_rug, t_yaw)
        # a few things on the far corners of the support (clear of the support point)
        m_cloth = b.material(_Material("cloth", _solid(_lin(1, 1, 1), nz, 0.1, 20.0)))
        m_ceramic = b.material(_Material("ceramic", _solid(_lin(1, 1, 1), nz, 0.04, 3.0)))
        side = 1 if rng.random() < 0.5 else -1
        corner = top_c + side * (tlen / 2 - 0.2) * tx + (tdep / 2 - 0.17) * tz
        y = 0.0
        for k in range(int(rng.integers(2, 4))):
            bt = rng.uniform(0.025, 0.05)
            b.box(corner + [0, y + bt / 2, 0], [rng.uniform(0.18, 0.26), bt, rng.uniform(0.13, 0.18)], m_cloth,
                  t_yaw + rng.uniform(-0.3, 0.3), tint=_hsv(rng.random(), rng.uniform(0.4, 0.8), rng.uniform(0.3, 0.8)))
            y += bt
        corner2 = top_c - side * (tlen / 2 - 0.16) * tx + (tdep / 2 - 0.16) * tz
        if kitchen:
            m_fruit = b.material(_Material("fruit", _solid(_lin(1, 1, 1), nz, 0.1, 10.0)))
            b.cylinder(corner2, 0.11, 0.05, m_ceramic, top_radius=0.14, tint=_hsv(rng.random(), 0.2, 0.85))
            for k in range(4):
                a = k * 1.7
                b.sphere(corner2 + [0.06 * math.cos(a), 0.08 + 0.02 * (k == 3), 0.06 * math.sin(a)], 0.04, m_fruit, 10, 16,
                         tint=[_lin(0.8, 0.15, 0.1), _lin(0.95, 0.6, 0.1), _lin(0.5, 0.75, 0.2), _lin(0.9, 0.8, 0.2)][k])
        else:
            vh = rng.uniform(0.18, 0.3)
            b.cylinder(corner2, rng.uniform(0.05, 0.08), vh, m_ceramic, top_radius=rng.uniform(0.035, 0.06),
                       tint=_hsv(rng.random(), rng.uniform(0.3, 0.8), rng.uniform(0.4, 0.85)))

        # --- furniture around
        m_dark_wood = b.material(_Material("dark_wood", _wood(wood_l * 0.6, wood_d * 0.4, nz, 20.0)))
        m_fabric = b.material(_Material("fabric", _solid(_lin(1, 1, 1), nz, 0.12, 15.0)))
        m_leaf = b.material(_Material("foliage", _stone(_lin(0.35, 0.6, 0.25), _lin(0.08, 0.25, 0.06), nz, 7.0)))
        m_pot = b.material(_Material("terracotta", _solid(_lin(0.72, 0.38, 0.24), nz, 0.1)))
        fabric_col = _hsv(rng.random(), rng.uniform(0.3, 0.7), rng.uniform(0.35, 0.7))
        # chairs on the far side and at the ends of the table
        n_ch = 0 if kitchen else int(rng.integers(1, 4))
        spots = [(0.0, 1.0), (-1.0, 0.0), (1.0, 0.0)]
        for i in rng.permutation(3)[:n_ch]:
            sx, sz = spots[i]
            cyaw = t_yaw + (math.pi if sz > 0 else (math.pi / 2 if sx < 0 else -math.pi / 2))
            pc = tc + sx * (tlen / 2 + 0.3) * tx + sz * (tdep / 2 + 0.3) * tz
            Rc = _rot_y(cyaw)
            b.box(pc + [0, 0.45, 0], [0.44, 0.05, 0.44], m_fabric, cyaw, tint=fabric_col)
            b.box(pc + [0, 0.75, 0] - 0.2 * Rc[:, 2], [0.44, 0.55, 0.04], m_dark_wood, cyaw)
            for lx in (-0.19, 0.19):
                for lz in (-0.19, 0.19):
                    b.box(pc + lx * Rc[:, 0] + lz * Rc[:, 2] + [0, 0.215, 0], [0.04, 0.43, 0.04], m_dark_wood, cyaw)
        if kitchen:
            # counter run along the far wall, upper cabinets, backsplash, fridge
            m_counter = b.material(_Material("countertop", _stone(_lin(0.5, 0.5, 0.5), _lin(0.12, 0.12, 0.13), nz, 6.0)))
            sp = _hsv(rng.random(), rng.uniform(0.0, 0.3), rng.uniform(0.5, 0.9))
            m_splash = b.material(_Material("backsplash", _tiles(sp, sp * 0.9, _lin(0.85, 0.85, 0.85), nz, 0.12, False, axes=(0, 1))))
            m_steel = b.material(_Material("steel", _solid(_lin(0.62, 0.63, 0.65), nz, 0.04, 30.0)))
            b.box([0, 0.44, z1 - 0.31], [W - 0.02, 0.88, 0.6], m_cab)
            b.box([0, 0.9, z1 - 0.31], [W - 0.02, 0.04, 0.62], m_counter)
            b.box([0, 1.2, z1 - 0.005], [W - 0.02, 0.56, 0.01], m_splash)
            b.box([0, 1.85, z1 - 0.18], [W - 0.02, 0.75, 0.35], m_cab)
            fx = x1 - 0.45 if rng.random() < 0.5 else x0 + 0.45
            b.box([fx, 1.0, z1 - 0.36], [0.85, 2.0, 0.7], m_steel)
            n_st = int(rng.integers(2, 4))
            for k in range(n_st):  # bar stools on the far side of the island
                sp_ = tc + (tdep / 2 + 0.3) * tz + (k - (n_st - 1) / 2) * 0.5 * tx
                b.cylinder(sp_, 0.02, 0.62, m_steel, 12)
                b.cylinder(sp_ + [0, 0.62, 0], 0.17, 0.05, m_fabric, 24, tint=fabric_col)
        else:
            # bookshelf against the far wall
            bw, bh, bd = rng.uniform(0.9, 1.4), rng.uniform(1.6, 2.1), 0.32
            bs_side = -1 if rng.random() < 0.5 else 1
            bx = bs_side * rng.uniform(0.2, 0.32) * W
            zc = z1 - bd / 2 - 0.02
            b.box([bx, bh / 2, z1 - 0.03], [bw, bh, 0.02], m_dark_wood)
            for sx in (-1, 1):
                b.box([bx + sx * (bw / 2 - 0.01), bh / 2, zc], [0.02, bh, bd], m_dark_wood)
            n_sh = 4
            for k in range(n_sh + 1):
                ys = 0.05 + k * (bh - 0.1) / n_sh
                b.box([bx, ys, zc], [bw, 0.025, bd], m_dark_wood)
                if k == n_sh:
                    break
                xb = bx - bw / 2 + 0.03
                while True:
                    wb = rng.uniform(0.025, 0.06)
                    hb = rng.uniform(0.6, 0.9) * (bh - 0.1) / n_sh
                    if xb + wb > bx + bw / 2 - 0.03:
                        break
                    if rng.random() < 0.88:
                        b.box([xb + wb / 2, ys + 0.0125 + hb / 2, zc + 0.02], [wb, hb, rng.uniform(0.18, 0.24)], m_cloth,
                              tint=_hsv(rng.random(), rng.uniform(0.3, 0.8), rng.uniform(0.2, 0.8)))
                    xb += wb + 0.002
            # sideboard on the other side with a vase and a plant
            sw, sh = rng.uniform(1.0, 1.5), rng.uniform(0.7, 0.9)
            sx_ = -bs_side * rng.uniform(0.18, 0.28) * W
            cab_col = _hsv(rng.random(), rng.uniform(0.1, 0.5), rng.uniform(0.3, 0.8))
            m_cab = b.material(_Material("cabinet", _cabinet(cab_col, nz, sw / 3, cab_col * 0.4)))
            b.box([sx_, sh / 2 + 0.08, z1 - 0.25], [sw, sh, 0.45], m_cab)
            for lx in (-1, 1):
                b.box([sx_ + lx * (sw / 2 - 0.05), 0.04, z1 - 0.25], [0.04, 0.08, 0.4], m_dark_wood)
            b.cylinder([sx_ + sw / 4, sh + 0.08, z1 - 0.25], 0.07, 0.32, m_ceramic, top_radius=0.045,
                       tint=_hsv(rng.random(), rng.uniform(0.2, 0.7), rng.uniform(0.5, 0.9)))
            b.cylinder([sx_ - sw / 4, sh + 0.08, z1 - 0.25], 0.08, 0.15, m_pot)
            b.rock([sx_ - sw / 4, sh + 0.08 + 0.3, z1 - 0.25], [0.2, 0.2, 0.2], m_leaf, rng, nz)
        # plant in a corner, ball on the floor
        pcx = x0 + 0.35 if rng.random() < 0.5 else x1 - 0.35
        pcz = z1 - rng.uniform(0.35, 1.8)
        ph_ = rng.uniform(0.35, 0.5)
        b.cylinder([pcx, 0, pcz], 0.2, ph_, m_pot, top_radius=0.24)
        for k in range(3):
            b.rock([pcx + rng.uniform(-0.1, 0.1), ph_ + 0.25 + 0.3 * k, pcz + rng.uniform(-0.1, 0.1)],
                   [0.32 - 0.06 * k] * 3, m_leaf, rng, nz)
        ball_c = np.array([rng.uniform(x0 + 0.6, x1 - 0.6), 0.0, rng.uniform(tc[2] + tdep / 2 + 0.8, z1 - 0.8)])
        br = rng.uniform(0.12, 0.2)
        ball_c[1] = br
        stripe_cols = np.stack([_hsv(rng.random(), 0.8, 0.9) for _ in range(3)] + [_lin(0.95, 0.95, 0.95)])

        def ball(p, n):
            k = np.floor((np.arctan2(p[:, 2], p[:, 0]) / (2 * np.pi) + 0.5) * 8).astype(np.int64) % 4
            return stripe_cols[k]

        m_ball = b.material(_Material("ball", ball, origin=ball_c))
        b.sphere(ball_c, br, m_ball, 16, 32)

        # --- paintings and window on the walls
        def wall_frame(wall: str, u: float, y: float):
            """(origin, axes) of a wall-local frame: x along the wall (to the right seen from inside),
            y up, z out of the wall into the room."""
            if wall == "far":
                return np.array([u, y, z1]), np.stack([[1, 0, 0], [0, 1, 0], [0, 0, -1]], 1).astype(float)
            if wall == "left":
                return np.array([x0, y, u]), np.stack([[0, 0, 1], [0, 1, 0], [1, 0, 0]], 1).astype(float)
            return np.array([x1, y, u]), np.stack([[0, 0, -1], [0, 1, 0], [-1, 0, 0]], 1).astype(float)

        win_wall = "left" if rng.random() < 0.5 else "right"
        other = "right" if win_wall == "left" else "left"
        m_frame = b.material(_Material("frame", _solid(_lin(0.25, 0.18, 0.1), nz, 0.1, 20.0)))
        sky_top = _lin(0.45, 0.65, 0.95)
        sky_bot = _lin(0.92, 0.95, 1.0)
        win_w, win_h = rng.uniform(1.0, 1.5), rng.uniform(1.1, 1.4)
        wu = rng.uniform(2.4, D - 1.2)
        wy = rng.uniform(0.9, 1.1)
        o, A = wall_frame(win_wall, wu, wy)
        o = o - A[:, 0] * win_w / 2

        def window(p, n):
            v = np.clip(p[:, 1] / win_h, 0, 1)
            c = _mix(sky_bot, sky_top, v)
            hills = v < 0.22 + 0.06 * np.sin(p[:, 0] * 5.0 + 1.3) + 0.03 * np.sin(p[:, 0] * 13.0)
            c[hills] = _lin(0.55, 0.7, 0.5)
            return c * 1.0

        m_win = b.material(_Material("window", window, emissive=True, casts_shadow=False, origin=o, axes=A))
        P = [o + A[:, 2] * 0.004 + A[:, 0] * a_ + A[:, 1] * c_ for a_, c_ in ((0, 0), (win_w, 0), (win_w, win_h), (0, win_h))]
        b.quad(*P, m_win)
        for a_, c_, sa, sc in ((win_w / 2, 0, win_w + 0.1, 0.06), (win_w / 2, win_h, win_w + 0.1, 0.06),
                               (0, win_h / 2, 0.06, win_h), (win_w, win_h / 2, 0.06, win_h),
                               (win_w / 2, win_h / 2, 0.04, win_h), (win_w / 2, win_h * 0.6, win_w, 0.04)):
            ctr = o + A[:, 0] * a_ + A[:, 1] * c_ + A[:, 2] * 0.03
            size = np.abs(A[:, 0]) * sa + np.abs(A[:, 1]) * sc + np.abs(A[:, 2]) * 0.05
            b.box(ctr, size, m_white)
        paintings = [("far", rng.uniform(-0.35, 0.35) * W)]
        if not kitchen:
            paintings += [("far", paintings[0][1] + (1 if paintings[0][1] < 0 else -1) * rng.uniform(1.0, 1.5)),
                          (other, rng.uniform(2.0, D - 1.0))]
        else:
            paintings = [(other, rng.uniform(2.0, D - 1.0))]
        for k, (wall, u) in enumerate(paintings):
            pw_, ph2 = rng.uniform(0.5, 1.0), rng.uniform(0.4, 0.8)
            py = rng.uniform(1.35, 1.6) if not (kitchen and wall == "far") else 2.3
            o, A = wall_frame(wall, u, py)
            o = o - A[:, 0] * pw_ / 2 + A[:, 2] * 0.03
            ctr = o + A[:, 0] * pw_ / 2 + A[:, 1] * ph2 / 2 - A[:, 2] * 0.015
            size = np.abs(A[:, 0]) * (pw_ + 0.08) + np.abs(A[:, 1]) * (ph2 + 0.08) + np.abs(A[:, 2]) * 0.03
            b.box(ctr, size, m_frame)
            m_p = b.material(_Material(f"painting_{k}", _painting(rng, nz, pw_, ph2), origin=o, axes=A))
            P = [o + A[:, 2] * 0.002 + A[:, 0] * a_ + A[:, 1] * c_ for a_, c_ in ((0, 0), (pw_, 0), (pw_, ph2), (0, ph2))]
            b.quad(*P, m_p)

        # --- ceiling lamp (the key light)
        lp = np.array([tc[0] + rng.uniform(-0.8, 0.8), Hc - rng.uniform(0.45, 0.7), tc[2] + rng.uniform(-0.3, 0.6)])
        warm = rng.uniform(0.0, 0.12)
        m_lamp = b.material(_Material("lamp", _solid(_lin(1.0, 0.95 - warm / 2, 0.85 - warm), nz, 0.0), emissive=True, casts_shadow=False))
        b.sphere(lp, 0.09, m_lamp, 10, 20)
        b.cylinder(lp + [0, 0.09, 0], 0.004, Hc - lp[1] - 0.09, m_frame, 8, caps=False)
        d_top = np.linalg.norm(lp - top_c)
        inten = rng.uniform(0.65, 0.8) * (d_top**2 + 0.6)
        light = dict(
            kind="point", vector=lp, falloff=0.6,
            color=inten * _lin(1.0, 0.96 - warm / 2, 0.9 - warm),
            ambient_sky=_lin(0.55, 0.55, 0.57) * rng.uniform(0.8, 0.95),
            ambient_ground=_lin(0.45, 0.43, 0.41) * rng.uniform(0.75, 0.9),
        )
        return dict(camera=camera, support=top_c, light=light, env=None)

    def _build_outdoor(self, rng: np.random.Generator) -> dict:
        b, nz = self._b, self._noise
        cam_h = rng.uniform(1.35, 1.5)
        heading = rng.uniform(0, 2 * np.pi)
        cam = np.array([0.0, cam_h, 0.0])
        fwd = np.array([math.sin(heading), 0.0, math.cos(heading)])
        tdist = rng.uniform(1.3, 1.5)
        tc = cam * [1, 0, 1] + tdist * fwd
        top_h = rng.uniform(0.74, 0.82)
        t_yaw = heading + rng.uniform(-0.2, 0.2)
        Rt = _rot_y(t_yaw)
        tx = Rt[:, 0]
        tlen, tdep = rng.uniform(1.2, 1.6), rng.uniform(0.75, 0.95)
        target = tc + [0, top_h, 0]
        camera = self._set_camera(cam, target, math.radians(rng.uniform(-1.5, 1.5)), top_h, tdist, offset=0.65)

        # --- sun and sky
        sun_az = heading + rng.uniform(-2.3, 2.3)
        sun_el = rng.uniform(math.radians(25), math.radians(55))
        sun = np.array([math.cos(sun_el) * math.sin(sun_az), math.sin(sun_el), math.cos(sun_el) * math.cos(sun_az)])
        zen = _hsv(rng.uniform(0.55, 0.62), rng.uniform(0.55, 0.75), rng.uniform(0.75, 0.9)) * 0.9
        hor = _lin(0.82, 0.87, 0.93) * rng.uniform(0.9, 1.0)
        cloud_amt = rng.uniform(0.0, 0.6)
        sun_col = _lin(1.0, 0.95, 0.85)

        def sky_dir(dw: np.ndarray) -> np.ndarray:
            dw = dw / np.linalg.norm(dw, axis=1, keepdims=True)
            el = dw[:, 1]
            c = _mix(hor, zen, np.power(np.clip(el, 0, 1), 0.45))
            if cloud_amt > 0:
                up_ = np.maximum(el, 0.05)[:, None]
                q = dw[:, [0, 2]] / up_
                cl = nz.fbm(np.stack([q[:, 0], q[:, 1], np.zeros(len(q))], 1).astype(np.float32), 1.2, 4)
                cm = _smoothstep(0.55 - 0.15 * cloud_amt, 0.75, cl) * _smoothstep(0.0, 0.15, el) * cloud_amt
                c = _mix(c, _lin(0.95, 0.95, 0.96), cm)
            cs = dw @ sun
            glow = np.clip((cs - 0.96) / 0.04, 0, 1) ** 3 * 0.35
            c = c + glow[:, None] * sun_col
            c[cs > math.cos(math.radians(1.6))] = sun_col * 4.0
            c[el < 0] = hor * 0.8
            return c.astype(np.float32)

        sky_R = 2000.0
        m_sky = b.material(_Material("sky", lambda p, n: sky_dir(p), emissive=True, casts_shadow=False,
                                     origin=np.array([cam[0], 0.0, cam[2]])))
        th = np.linspace(0, np.pi, 49)
        ph = np.linspace(0, 2 * np.pi, 96, endpoint=False)
        th, ph = np.meshgrid(th, ph, indexing="ij")
        u = np.stack([np.sin(th) * np.cos(ph), np.cos(th), np.sin(th) * np.sin(ph)], -1)
        b.grid(u * sky_R + [cam[0], 0, cam[2]], m_sky, normals=-u, wrap=True)

        # --- ground
        sand = _hsv(rng.uniform(0.08, 0.12), rng.uniform(0.3, 0.5), rng.uniform(0.6, 0.75))
        grass = _hsv(rng.uniform(0.18, 0.3), rng.uniform(0.45, 0.7), rng.uniform(0.35, 0.55))
        dirt = _hsv(rng.uniform(0.06, 0.1), rng.uniform(0.4, 0.6), rng.uniform(0.3, 0.45))
        grass_amt = rng.uniform(0.2, 0.8)

        def ground(p, n):
            r = np.hypot(p[:, 0], p[:, 2])
            big = nz.fbm(p, 0.08, 3)
            g = _smoothstep(0.55 - 0.4 * grass_amt, 0.62 - 0.4 * grass_amt, big)
            c = _mix(sand, grass, g)
            detail = np.exp(-r / 60.0).astype(np.float32)
            mid = nz.fbm(p, 0.7, 2)
            c = _mix(c, dirt, np.clip((mid - 0.6) * 3.0, 0, 1) * 0.7)
            fine = nz.fbm(p, 6.0, 2)
            return c * (1.0 + detail * 0.35 * (fine - 0.5))[:, None]

        m_ground = b.material(_Material("ground", ground))
        g = np.array([-1500, -600, -200, -60, -20, -6, -2, 0, 2, 6, 20, 60, 200, 600, 1500], np.float64)
        gx, gz = np.meshgrid(g + cam[0], g + cam[2], indexing="ij")
        P = np.stack([gx, np.zeros_like(gx), gz], -1)
        b.grid(P, m_ground, normals=np.tile([0.0, 1.0, 0.0], (P.shape[0] * P.shape[1], 1)))

        # --- mountains: a ring heightfield, hundreds of metres away
        r0, r1 = rng.uniform(450, 650), rng.uniform(1000, 1200)
        n_th, n_r = 540, 14
        th = np.linspace(0, 2 * np.pi, n_th, endpoint=False)
        rr = np.linspace(0, 1, n_r)
        RR, TH = np.meshgrid(rr, th, indexing="ij")  # rows: radius, columns: angle (wrapped)
        ring = np.stack([np.cos(TH) * 3.0, np.sin(TH) * 3.0, RR * 2.0], -1).reshape(-1, 3).astype(np.float32)
        hmax = rng.uniform(90, 200)
        h = (0.15 + 0.85 * nz.fbm(ring + 20.0, 1.0, 5)).reshape(n_r, n_th) * hmax
        prof = np.clip(RR / 0.55, 0, 1) ** 0.8
        Y = h * prof - 5.0
        R_ = r0 + (r1 - r0) * RR
        P = np.stack([np.sin(TH) * R_ + cam[0], Y, np.cos(TH) * R_ + cam[2]], -1)
        rock_c = _hsv(rng.uniform(0.05, 0.12), rng.uniform(0.1, 0.3), rng.uniform(0.35, 0.5))
        snow_line = hmax * rng.uniform(0.55, 0.8)

        def mountain(p, n):
            c = _mix(rock_c * 0.6, rock_c, nz.fbm(p, 0.02, 3))
            veg = _smoothstep(0.6, 0.3, p[:, 1] / hmax) * _smoothstep(0.6, 0.9, n[:, 1])
            c = _mix(c, grass * 0.6, veg * 0.8)
            snow = (p[:, 1] + 30.0 * (nz.fbm(p, 0.03, 2) - 0.5) > snow_line) & (n[:, 1] > 0.55)
            c[snow] = _lin(0.92, 0.93, 0.95)
            return c

        m_mtn = b.material(_Material("mountain", mountain, origin=np.array([cam[0], 0.0, cam[2]])))
        b.grid(P, m_mtn, wrap=True)

        # --- the stone table
        stone_l = _hsv(rng.uniform(0.05, 0.12), rng.uniform(0.05, 0.25), rng.uniform(0.6, 0.75))
        m_stone = b.material(_Material("stone", _stone(stone_l, stone_l * 0.55, nz, 3.0), origin=tc, axes=Rt))
        top_c = tc + np.array([0, top_h, 0])
        slab = rng.uniform(0.07, 0.1)
        b.box(top_c - [0, slab / 2, 0], [tlen, slab, tdep], m_stone, t_yaw)
        for sx in (-1, 1):
            lc = tc + sx * (tlen / 2 - 0.22) * tx
            b.box(lc + [0, (top_h - slab) / 2, 0], [0.22, top_h - slab, tdep - 0.2], m_stone, t_yaw)

        # --- rocks, crates, trees
        m_rock = b.material(_Material("rock", _stone(_lin(0.7, 0.66, 0.6), _lin(0.3, 0.28, 0.25), nz, 1.5)))
        m_crate = b.material(_Material("crate", _planks(_lin(0.62, 0.45, 0.28), _lin(0.35, 0.22, 0.12), nz, 0.12, 0.6,
                                                        _lin(0.15, 0.1, 0.05))))
        m_bark = b.material(_Material("bark", _stone(_lin(0.35, 0.25, 0.18), _lin(0.12, 0.08, 0.05), nz, 8.0)))
        m_leaf = b.material(_Material("foliage", _stone(grass * 1.2, grass * 0.45, nz, 3.0)))

        def place(rmin, rmax, clearance):
            front = rng.random() < 0.6  # most objects in front of the camera
            for _ in range(50):
                a = heading + (rng.uniform(-0.9, 0.9) if front else rng.uniform(-np.pi, np.pi))
                r = rng.uniform(rmin, rmax)
                q = cam * [1, 0, 1] + r * np.array([math.sin(a), 0, math.cos(a)])
                if np.hypot(*(q - tc)[[0, 2]]) > clearance + 1.1 and np.hypot(*(q - cam)[[0, 2]]) > clearance + 0.6:
                    return q
            return q

        for k in range(int(rng.integers(9, 16))):
            s = rng.uniform(0.25, 1.4)
            q = place(3.0, 35.0, s)
            rad = s * rng.uniform(0.7, 1.3, 3)
            b.rock(q + [0, rad[1] * 0.35, 0], rad, m_rock, rng, nz, tint=_lin(*([rng.uniform(0.85, 1.0)] * 3)))
        for k in range(int(rng.integers(1, 4))):
            q = place(2.5, 8.0, 0.6)
            s = rng.uniform(0.4, 0.7)
            b.box(q + [0, s / 2, 0], [s, s, s], m_crate, rng.uniform(0, np.pi))
        for k in range(int(rng.integers(4, 9))):
            q = place(7.0, 50.0, 3.0)
            hgt = rng.uniform(2.0, 4.0)
            b.cylinder(q, rng.uniform(0.15, 0.3), hgt, m_bark, 16)
            cr = rng.uniform(1.4, 2.8)
            b.rock(q + [0, hgt + cr * 0.6, 0], [cr, cr * rng.uniform(0.8, 1.2), cr], m_leaf, rng, nz)

        light = dict(
            kind="directional", vector=sun,
            color=rng.uniform(0.8, 0.95) * sun_col,
            ambient_sky=(zen * 0.3 + hor * 0.2) * rng.uniform(0.9, 1.1),
            ambient_ground=sand * 0.25,
        )
        return dict(camera=camera, support=top_c, light=light, env=sky_dir)
