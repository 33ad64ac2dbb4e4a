"""Procedural materials: 3-D albedo functions of object-local points and normals.

Every texture constructor returns a function ``f(p, n)`` that takes object-local points and
normals, both (M, 3), and returns linear RGB (M, 3): the diffuse albedo, or the emitted radiance
of an emissive :class:`Material`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from snell_bench.scene.procedural.color import hsv, lin
from snell_bench.scene.procedural.noise import Noise, fract, mix, smoothstep

__all__ = [
    "Material",
    "solid",
    "wood",
    "planks",
    "rug",
    "wallpaper",
    "tiles",
    "marble",
    "stone",
    "cabinet",
    "painting",
]

Albedo = Callable[[np.ndarray, np.ndarray], np.ndarray]


@dataclass
class Material:
    """A procedural material.

    Attributes:
        name: Unique name; a builder registers each name once.
        albedo: ``albedo(p, n)`` maps object-local points/normals (M, 3) to linear RGB (M, 3).
        emissive: Whether ``albedo`` is emitted radiance (unlit) rather than diffuse albedo.
        casts_shadow: Whether the surface blocks shadow rays.
        origin: Origin of the local frame in world coordinates (``None``: the world origin).
        axes: Columns are the local axes in world coordinates (``None``: the world axes).
    """

    name: str
    albedo: Albedo
    emissive: bool = False
    casts_shadow: bool = True
    origin: np.ndarray | None = None
    axes: np.ndarray | None = None


def solid(color, noise: Noise, amount: float = 0.08, freq: float = 6.0) -> Albedo:
    """A flat colour modulated by ``±amount`` of low-frequency noise at ``freq``."""
    color = np.asarray(color, np.float32)

    def f(p, n):
        v = noise.fbm(p, freq, 2)
        return color[None, :] * (1.0 - amount + 2.0 * amount * v)[:, None]

    return f


def wood(light, dark, noise: Noise, ring_freq: float = 9.0, grain: float = 1.0) -> Albedo:
    """Wood with growth rings around an axis parallel to local x, below the local origin.

    Args:
        light: Early-wood colour.
        dark: Late-wood (ring) colour.
        noise: Noise source.
        ring_freq: Rings per metre of radius.
        grain: Strength of the fine grain.
    """

    def f(p, n):
        y = p[:, 1] + 0.35 + 0.05 * np.sin(p[:, 0] * 1.7)
        warp = noise.fbm(p, (0.5, 2.0, 2.0), 3)
        r = np.sqrt(y**2 + p[:, 2] ** 2) * ring_freq + 3.0 * warp
        rings = fract(r)
        rings = smoothstep(0.0, 0.75, rings) * smoothstep(1.0, 0.85, rings)
        fine = noise.fbm(p, (2.0, 60.0, 60.0), 2)
        t = np.clip(0.6 * rings + grain * 0.7 * (fine - 0.5) + 0.15 * (warp - 0.5), 0, 1)
        return mix(light, dark, t)

    return f


def planks(light, dark, noise: Noise, width: float, length: float, seam) -> Albedo:
    """Floor planks running along local x, ``width`` across (local z) and ``length`` long.

    Args:
        light: Light wood colour.
        dark: Dark wood colour.
        noise: Noise source.
        width: Plank width (m).
        length: Plank length (m); rows are staggered randomly.
        seam: Colour of the gaps between planks.
    """
    seam = np.asarray(seam, np.float32)

    def f(p, n):
        row = np.floor(p[:, 2] / width)
        xs = p[:, 0] + noise.cell(row.astype(np.int64), 7) * length
        col = np.floor(xs / length)
        tone = noise.cell(row.astype(np.int64), col.astype(np.int64), 3)
        q = np.stack([xs - col * length, p[:, 1], p[:, 2] - row * width - 0.5 * width + 0.4 * tone], 1)
        r = np.sqrt(q[:, 1] ** 2 + (q[:, 2] + 0.6) ** 2) * 14.0 + 2.0 * noise.fbm(
            q * 1.0 + tone[:, None] * 9, (0.6, 3, 3), 2
        )
        rings = fract(r)
        rings = smoothstep(0.0, 0.6, rings) * smoothstep(1.0, 0.75, rings)
        fine = noise.fbm(q + tone[:, None] * 17, (1.2, 25.0, 40.0), 2)
        c = mix(light, dark, np.clip(0.3 * tone + 0.35 * rings + 0.35 * fine, 0, 1))
        u = fract(p[:, 2] / width)
        v = fract(xs / length)
        edge = np.minimum(np.minimum(u, 1 - u) * width, np.minimum(v, 1 - v) * length)
        s = smoothstep(0.0015, 0.004, edge)
        return mix(seam, c, s)

    return f


def rug(colors, noise: Noise, half_x: float, half_z: float, style: int) -> Albedo:
    """A rug centred at the local origin; local x and z span it.

    Args:
        colors: Three colours: the two of the inner pattern and the border band.
        noise: Noise source (fibres).
        half_x: Half extent along local x (m).
        half_z: Half extent along local z (m).
        style: Inner pattern: 0 stripes, 1 checker, anything else diamonds.
    """
    c0, c1, c2 = [np.asarray(c, np.float32) for c in colors]

    def f(p, n):
        ax, az = np.abs(p[:, 0]), np.abs(p[:, 2])
        bx, bz = half_x - ax, half_z - az
        border = np.minimum(bx, bz)
        if style == 0:  # stripes
            v = fract(p[:, 0] * 4.0)
            inner = np.where(v < 0.5, 0.0, 1.0)
        elif style == 1:  # checker
            inner = ((np.floor(p[:, 0] * 5.0) + np.floor(p[:, 2] * 5.0)) % 2).astype(np.float32)
        else:  # diamonds
            inner = (fract((ax + az) * 4.0) < 0.5).astype(np.float32)
        col = mix(c0, c1, inner)
        band = (border < 0.12).astype(np.float32) * (border > 0.04)
        col = mix(col, c2, band)
        fib = noise.fbm(p, 60.0, 2)
        return col * (0.82 + 0.36 * fib)[:, None]

    return f


def wallpaper(base, stripe, noise: Noise, period: float, width: float) -> Albedo:
    """Vertical stripes along ``u = x + z`` (walls are axis-aligned).

    Args:
        base: Background colour.
        stripe: Stripe colour.
        noise: Noise source.
        period: Stripe period along the wall (m).
        width: Stripe width as a fraction of ``period``.
    """

    def f(p, n):
        u = p[:, 0] + p[:, 2]
        s = fract(u / period)
        m = smoothstep(0.0, 0.01, s) * smoothstep(width + 0.01, width, s)
        thin = np.abs(s - (width + 1.0) / 2.0) < 0.015
        c = mix(base, stripe, np.maximum(m, 0.7 * thin))
        return c * (0.92 + 0.16 * noise.fbm(p, 8.0, 2))[:, None]

    return f


def tiles(c0, c1, grout, noise: Noise, size: float, checker: bool, axes=(0, 2)) -> Albedo:
    """Square tiles in the local ``(axes[0], axes[1])`` plane with grout lines.

    Args:
        c0: First tile colour.
        c1: Second tile colour (checker), or the colour each tile leans towards by up to 25 %.
        grout: Grout colour.
        noise: Noise source.
        size: Tile side (m).
        checker: Alternate ``c0``/``c1`` in a checkerboard instead of varying each tile slightly.
        axes: The two local axes spanning the tiled plane.
    """
    grout = np.asarray(grout, np.float32)

    def f(p, n):
        a, b = p[:, axes[0]] / size, p[:, axes[1]] / size
        ia, ib = np.floor(a), np.floor(b)
        if checker:
            t = ((ia + ib) % 2).astype(np.float32)
        else:
            t = 0.25 * noise.cell(ia.astype(np.int64), ib.astype(np.int64), 5)
        col = mix(c0, c1, t) * (0.9 + 0.2 * noise.fbm(p, 3.0, 2))[:, None]
        fa, fb = a - ia, b - ib
        edge = np.minimum(np.minimum(fa, 1 - fa), np.minimum(fb, 1 - fb)) * size
        return mix(grout, col, smoothstep(0.002, 0.004, edge))

    return f


def marble(base, vein, noise: Noise) -> Albedo:
    """White marble with thin, turbulent dark veins of colour ``vein`` on ``base``."""

    def f(p, n):
        w = noise.fbm(p, 1.2, 5)
        ph = (p[:, 0] * 1.1 + p[:, 2] * 0.7) * 5.0 + 9.0 * w
        v = np.abs(np.sin(ph))
        thick = 0.04 + 0.1 * noise.fbm(p, 2.0, 2)
        vm = 1.0 - smoothstep(0.0, 1.0, v / thick)
        w2 = noise.fbm(p + 13.0, 3.0, 3)
        v2 = 1.0 - smoothstep(0.0, 0.03, np.abs(np.sin((p[:, 0] * 0.6 - p[:, 2]) * 7.0 + 7.0 * w2)))
        t = np.clip(0.85 * vm + 0.4 * v2, 0, 1)
        c = mix(base, vein, t)
        return c * (0.94 + 0.1 * noise.fbm(p, 6.0, 2))[:, None]

    return f


def stone(light, dark, noise: Noise, freq: float = 2.0) -> Albedo:
    """Mottled stone (also foliage and bark): noise at ``freq`` blends ``dark`` into ``light``."""

    def f(p, n):
        a = noise.fbm(p, freq, 4)
        s = noise.noise(p * 40.0)
        return mix(dark, light, np.clip(1.6 * (a - 0.5) + 0.5 + 0.25 * (s - 0.5), 0, 1))

    return f


def cabinet(paint, noise: Noise, door: float, groove) -> Albedo:
    """Painted cabinet fronts: grooves of colour ``groove`` every ``door`` metres along u = x + z."""
    paint = np.asarray(paint, np.float32)
    groove = np.asarray(groove, np.float32)

    def f(p, n):
        u = fract((p[:, 0] + p[:, 2]) / door)
        e = np.minimum(u, 1 - u) * door
        c = mix(groove, paint, smoothstep(0.003, 0.006, e))
        return c * (0.95 + 0.1 * noise.fbm(p, 5.0, 2))[:, None]

    return f


def painting(rng: np.random.Generator, noise: Noise, w: float, h: float) -> Albedo:
    """A colourful canvas; local x in [0, w] (right), y in [0, h] (up).

    Args:
        rng: Draws the style, the palette and the composition.
        noise: Noise source (brush strokes).
        w: Canvas width (m).
        h: Canvas height (m).
    """
    style = int(rng.integers(4))
    hue0 = rng.random()
    pal = np.stack(
        [hsv(hue0 + rng.uniform(-0.35, 0.35), rng.uniform(0.45, 0.95), rng.uniform(0.45, 0.95)) for _ in range(5)]
    )
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
            col = mix(pal[i], pal[i + 1], smoothstep(0.3, 0.7, t - i))
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
            col = mix(pal[0] * 0.4 + 0.6, pal[1], v)
            sun = (u - 0.25 - 0.5 * params[0]) ** 2 * (w / h) ** 2 + (v - 0.7 - 0.2 * params[1]) ** 2 < 0.01
            col[sun] = lin(1.0, 0.9, 0.5)
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
