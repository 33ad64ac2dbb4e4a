"""Scene layout of the outdoor kind: a stone table on open ground, rocks, trees, mountains, sky."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from snell_bench.scene.procedural.builder import Builder
from snell_bench.scene.procedural.color import hsv, lin
from snell_bench.scene.procedural.frames import CameraPose, Layout, camera_pose
from snell_bench.scene.procedural.noise import Noise, mix, rot_y, smoothstep
from snell_bench.scene.procedural.shading import Light
from snell_bench.scene.procedural.textures import Material, planks, stone

__all__ = ["build_outdoor"]


@dataclass
class _Site:
    """The frame of the outdoor scene: the camera and the stone table in front of it.

    Attributes:
        cam: Camera position.
        heading: Direction the camera faces (yaw about y).
        tc: Centre of the table on the ground.
        top_h: Height of the table top.
        t_yaw: Yaw of the table; ``Rt`` is its rotation (derived).
        tlen: Table length (along its local x).
        tdep: Table depth (along its local z).
        camera: The camera pose.
    """

    cam: np.ndarray
    heading: float
    tc: np.ndarray
    top_h: float
    t_yaw: float
    tlen: float
    tdep: float
    camera: CameraPose

    def __post_init__(self) -> None:
        self.Rt = rot_y(self.t_yaw)


def build_outdoor(b: Builder, nz: Noise, rng: np.random.Generator, fov_x_deg: float) -> Layout:
    """Builds the outdoor scene (closed by a 2 km sky dome) and returns its layout.

    Args:
        b: Receives the geometry.
        nz: Noise source of the textures.
        rng: The scene's generator.
        fov_x_deg: Horizontal field of view of the camera (it sets the pitch).

    Returns:
        The layout, in the world frame.
    """
    site = _site(rng, fov_x_deg)
    sky_dir, sun, zen, hor, sun_col = _sky(b, nz, rng, site)
    sand, grass = _ground(b, nz, rng, site.cam)
    _mountains(b, nz, rng, site.cam, grass)
    top_c = _stone_table(b, nz, rng, site)
    _scatter(b, nz, rng, site, grass)
    light = Light(
        kind="directional",
        vector=sun,
        color=rng.uniform(0.8, 0.95) * sun_col,
        ambient_sky=(zen * 0.3 + hor * 0.2) * rng.uniform(0.9, 1.1),
        ambient_ground=sand * 0.25,
    )
    return Layout(camera=site.camera, support=top_c, light=light, env=sky_dir)


def _site(rng: np.random.Generator, fov_x_deg: float) -> _Site:
    """Draws the camera and the table's placement in front of it."""
    cam_h = rng.uniform(1.35, 1.5)
    heading = rng.uniform(0, 2 * np.pi)
    cam = np.array([0.0, cam_h, 0.0])
    fwd = np.array([math.sin(heading), 0.0, math.cos(heading)])
    tdist = rng.uniform(1.3, 1.5)
    tc = cam * [1, 0, 1] + tdist * fwd
    top_h = rng.uniform(0.74, 0.82)
    t_yaw = heading + rng.uniform(-0.2, 0.2)
    tlen, tdep = rng.uniform(1.2, 1.6), rng.uniform(0.75, 0.95)
    target = tc + [0, top_h, 0]
    camera = camera_pose(cam, target, fov_x_deg, math.radians(rng.uniform(-1.5, 1.5)), top_h, tdist, offset=0.65)
    return _Site(cam, heading, tc, top_h, t_yaw, tlen, tdep, camera)


def _sky(b: Builder, nz: Noise, rng: np.random.Generator, site: _Site):
    """The sun and an emissive sky dome with clouds, centred above the camera.

    Returns:
        ``(sky radiance of world directions, sun direction, zenith colour, horizon colour, sun
        colour)``.
    """
    cam = site.cam
    sun_az = site.heading + rng.uniform(-2.3, 2.3)
    sun_el = rng.uniform(math.radians(25), math.radians(55))
    sun = np.array([math.cos(sun_el) * math.sin(sun_az), math.sin(sun_el), math.cos(sun_el) * math.cos(sun_az)])
    zen = hsv(rng.uniform(0.55, 0.62), rng.uniform(0.55, 0.75), rng.uniform(0.75, 0.9)) * 0.9
    hor = lin(0.82, 0.87, 0.93) * rng.uniform(0.9, 1.0)
    cloud_amt = rng.uniform(0.0, 0.6)
    sun_col = lin(1.0, 0.95, 0.85)

    def sky_dir(dw: np.ndarray) -> np.ndarray:
        dw = dw / np.linalg.norm(dw, axis=1, keepdims=True)
        el = dw[:, 1]
        c = mix(hor, zen, np.power(np.clip(el, 0, 1), 0.45))
        if cloud_amt > 0:
            up_ = np.maximum(el, 0.05)[:, None]
            q = dw[:, [0, 2]] / up_
            cl = nz.fbm(np.stack([q[:, 0], q[:, 1], np.zeros(len(q))], 1).astype(np.float32), 1.2, 4)
            cm = smoothstep(0.55 - 0.15 * cloud_amt, 0.75, cl) * smoothstep(0.0, 0.15, el) * cloud_amt
            c = mix(c, lin(0.95, 0.95, 0.96), cm)
        cs = dw @ sun
        glow = np.clip((cs - 0.96) / 0.04, 0, 1) ** 3 * 0.35
        c = c + glow[:, None] * sun_col
        c[cs > math.cos(math.radians(1.6))] = sun_col * 4.0
        c[el < 0] = hor * 0.8
        return c.astype(np.float32)

    sky_R = 2000.0
    m_sky = b.material(
        Material(
            "sky", lambda p, n: sky_dir(p), emissive=True, casts_shadow=False, origin=np.array([cam[0], 0.0, cam[2]])
        )
    )
    th = np.linspace(0, np.pi, 49)
    ph = np.linspace(0, 2 * np.pi, 96, endpoint=False)
    th, ph = np.meshgrid(th, ph, indexing="ij")
    u = np.stack([np.sin(th) * np.cos(ph), np.cos(th), np.sin(th) * np.sin(ph)], -1)
    b.grid(u * sky_R + [cam[0], 0, cam[2]], m_sky, normals=-u, wrap=True)
    return sky_dir, sun, zen, hor, sun_col


def _ground(b: Builder, nz: Noise, rng: np.random.Generator, cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sandy ground with patches of grass and dirt, detail fading with distance from ``cam``.

    Returns:
        The ``(sand, grass)`` colours.
    """
    sand = hsv(rng.uniform(0.08, 0.12), rng.uniform(0.3, 0.5), rng.uniform(0.6, 0.75))
    grass = hsv(rng.uniform(0.18, 0.3), rng.uniform(0.45, 0.7), rng.uniform(0.35, 0.55))
    dirt = hsv(rng.uniform(0.06, 0.1), rng.uniform(0.4, 0.6), rng.uniform(0.3, 0.45))
    grass_amt = rng.uniform(0.2, 0.8)

    def ground(p, n):
        r = np.hypot(p[:, 0], p[:, 2])
        big = nz.fbm(p, 0.08, 3)
        g = smoothstep(0.55 - 0.4 * grass_amt, 0.62 - 0.4 * grass_amt, big)
        c = mix(sand, grass, g)
        detail = np.exp(-r / 60.0).astype(np.float32)
        mid = nz.fbm(p, 0.7, 2)
        c = mix(c, dirt, np.clip((mid - 0.6) * 3.0, 0, 1) * 0.7)
        fine = nz.fbm(p, 6.0, 2)
        return c * (1.0 + detail * 0.35 * (fine - 0.5))[:, None]

    m_ground = b.material(Material("ground", ground))
    g = np.array([-1500, -600, -200, -60, -20, -6, -2, 0, 2, 6, 20, 60, 200, 600, 1500], np.float64)
    gx, gz = np.meshgrid(g + cam[0], g + cam[2], indexing="ij")
    P = np.stack([gx, np.zeros_like(gx), gz], -1)
    b.grid(P, m_ground, normals=np.tile([0.0, 1.0, 0.0], (P.shape[0] * P.shape[1], 1)))
    return sand, grass


def _mountains(b: Builder, nz: Noise, rng: np.random.Generator, cam: np.ndarray, grass: np.ndarray) -> None:
    """A ring heightfield of mountains around ``cam``, hundreds of metres away, snow on top."""
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
    rock_c = hsv(rng.uniform(0.05, 0.12), rng.uniform(0.1, 0.3), rng.uniform(0.35, 0.5))
    snow_line = hmax * rng.uniform(0.55, 0.8)

    def mountain(p, n):
        c = mix(rock_c * 0.6, rock_c, nz.fbm(p, 0.02, 3))
        veg = smoothstep(0.6, 0.3, p[:, 1] / hmax) * smoothstep(0.6, 0.9, n[:, 1])
        c = mix(c, grass * 0.6, veg * 0.8)
        snow = (p[:, 1] + 30.0 * (nz.fbm(p, 0.03, 2) - 0.5) > snow_line) & (n[:, 1] > 0.55)
        c[snow] = lin(0.92, 0.93, 0.95)
        return c

    m_mtn = b.material(Material("mountain", mountain, origin=np.array([cam[0], 0.0, cam[2]])))
    b.grid(P, m_mtn, wrap=True)


def _stone_table(b: Builder, nz: Noise, rng: np.random.Generator, site: _Site) -> np.ndarray:
    """The support: a stone slab on two stone blocks. Returns the centre of its top."""
    tc, top_h, tlen, tdep, t_yaw = site.tc, site.top_h, site.tlen, site.tdep, site.t_yaw
    stone_l = hsv(rng.uniform(0.05, 0.12), rng.uniform(0.05, 0.25), rng.uniform(0.6, 0.75))
    m_stone = b.material(Material("stone", stone(stone_l, stone_l * 0.55, nz, 3.0), origin=tc, axes=site.Rt))
    top_c = tc + np.array([0, top_h, 0])
    slab = rng.uniform(0.07, 0.1)
    b.box(top_c - [0, slab / 2, 0], [tlen, slab, tdep], m_stone, t_yaw)
    for sx in (-1, 1):
        lc = tc + sx * (tlen / 2 - 0.22) * site.Rt[:, 0]
        b.box(lc + [0, (top_h - slab) / 2, 0], [0.22, top_h - slab, tdep - 0.2], m_stone, t_yaw)
    return top_c


def _scatter_point(rng: np.random.Generator, site: _Site, rmin: float, rmax: float, clearance: float) -> np.ndarray:
    """A ground point ``rmin``-``rmax`` from the camera, mostly in front of it, clear of the table
    and the camera by ``clearance`` (after at most 50 tries, the last one drawn)."""
    cam, tc, heading = site.cam, site.tc, site.heading
    front = rng.random() < 0.6  # most objects in front of the camera
    for _ in range(50):
        a = heading + (rng.uniform(-0.9, 0.9) if front else rng.uniform(-np.pi, np.pi))
        r = rng.uniform(rmin, rmax)
        q = cam * [1, 0, 1] + r * np.array([math.sin(a), 0, math.cos(a)])
        if np.hypot(*(q - tc)[[0, 2]]) > clearance + 1.1 and np.hypot(*(q - cam)[[0, 2]]) > clearance + 0.6:
            return q
    return q


def _scatter(b: Builder, nz: Noise, rng: np.random.Generator, site: _Site, grass: np.ndarray) -> None:
    """Rocks, wooden crates and trees scattered around the camera."""
    m_rock = b.material(Material("rock", stone(lin(0.7, 0.66, 0.6), lin(0.3, 0.28, 0.25), nz, 1.5)))
    m_crate = b.material(
        Material("crate", planks(lin(0.62, 0.45, 0.28), lin(0.35, 0.22, 0.12), nz, 0.12, 0.6, lin(0.15, 0.1, 0.05)))
    )
    m_bark = b.material(Material("bark", stone(lin(0.35, 0.25, 0.18), lin(0.12, 0.08, 0.05), nz, 8.0)))
    m_leaf = b.material(Material("foliage", stone(grass * 1.2, grass * 0.45, nz, 3.0)))
    for _ in range(int(rng.integers(9, 16))):
        s = rng.uniform(0.25, 1.4)
        q = _scatter_point(rng, site, 3.0, 35.0, s)
        rad = s * rng.uniform(0.7, 1.3, 3)
        b.rock(q + [0, rad[1] * 0.35, 0], rad, m_rock, rng, nz, tint=lin(*([rng.uniform(0.85, 1.0)] * 3)))
    for _ in range(int(rng.integers(1, 4))):
        q = _scatter_point(rng, site, 2.5, 8.0, 0.6)
        s = rng.uniform(0.4, 0.7)
        b.box(q + [0, s / 2, 0], [s, s, s], m_crate, rng.uniform(0, np.pi))
    for _ in range(int(rng.integers(4, 9))):
        q = _scatter_point(rng, site, 7.0, 50.0, 3.0)
        hgt = rng.uniform(2.0, 4.0)
        b.cylinder(q, rng.uniform(0.15, 0.3), hgt, m_bark, 16)
        cr = rng.uniform(1.4, 2.8)
        b.rock(q + [0, hgt + cr * 0.6, 0], [cr, cr * rng.uniform(0.8, 1.2), cr], m_leaf, rng, nz)
