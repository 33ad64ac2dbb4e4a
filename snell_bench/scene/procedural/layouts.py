"""The indoor scene layouts: a furnished living room and a kitchen with an island.

Their furnishings are in :mod:`snell_bench.scene.procedural.furniture`, the types a layout is made
of (:class:`~snell_bench.scene.procedural.frames.Layout`, the camera pose, the room frame) in
:mod:`snell_bench.scene.procedural.frames`, and the outdoor kind in
:mod:`snell_bench.scene.procedural.outdoor`. A layout function adds the scene's geometry to a
:class:`Builder` in the world frame (y up, metres) and returns a :class:`Layout`: the camera pose,
the support point and the light. Every random choice comes from the scene's generator, in a fixed
order, so a seed always gives the same scene.
"""

from __future__ import annotations

import math

import numpy as np

from snell_bench.scene.procedural.builder import Builder
from snell_bench.scene.procedural.color import hsv, lin
from snell_bench.scene.procedural.frames import Layout, Room, camera_pose
from snell_bench.scene.procedural.furniture import (
    bookshelf,
    ceiling_lamp,
    chairs,
    corner_plant,
    floor_ball,
    kitchen_counter,
    paintings,
    sideboard,
    tabletop_items,
    window,
)
from snell_bench.scene.procedural.noise import Noise, rot_y
from snell_bench.scene.procedural.textures import (
    Material,
    cabinet,
    marble,
    planks,
    rug,
    solid,
    stone,
    tiles,
    wallpaper,
    wood,
)

__all__ = ["build_room"]


def build_room(b: Builder, nz: Noise, rng: np.random.Generator, fov_x_deg: float, kitchen: bool) -> Layout:
    """Builds a living room (``kitchen=False``) or a kitchen and returns its layout.

    Args:
        b: Receives the geometry.
        nz: Noise source of the textures.
        rng: The scene's generator.
        fov_x_deg: Horizontal field of view of the camera (it sets the pitch).
        kitchen: Build the kitchen.

    Returns:
        The layout, in the world frame.
    """
    room = _room_frame(rng, fov_x_deg, kitchen)
    wood_l, wood_d, m_white = _shell(b, nz, rng, room)
    if kitchen:
        m_cab = _kitchen_island(b, nz, rng, room)
    else:
        _table(b, nz, rng, room, wood_l, wood_d)
    m_cloth, m_ceramic = tabletop_items(b, nz, rng, room)
    # furniture around
    m_dark_wood = b.material(Material("dark_wood", wood(wood_l * 0.6, wood_d * 0.4, nz, 20.0)))
    m_fabric = b.material(Material("fabric", solid(lin(1, 1, 1), nz, 0.12, 15.0)))
    m_leaf = b.material(Material("foliage", stone(lin(0.35, 0.6, 0.25), lin(0.08, 0.25, 0.06), nz, 7.0)))
    m_pot = b.material(Material("terracotta", solid(lin(0.72, 0.38, 0.24), nz, 0.1)))
    fabric_col = hsv(rng.random(), rng.uniform(0.3, 0.7), rng.uniform(0.35, 0.7))
    chairs(b, rng, room, m_fabric, m_dark_wood, fabric_col)
    if kitchen:
        kitchen_counter(b, nz, rng, room, m_cab, m_fabric, fabric_col)
    else:
        bs_side = bookshelf(b, rng, room, m_dark_wood, m_cloth)
        sideboard(b, nz, rng, room, bs_side, m_dark_wood, m_ceramic, m_pot, m_leaf)
    corner_plant(b, nz, rng, room, m_pot, m_leaf)
    floor_ball(b, rng, room)
    # a window on one side wall, paintings on the others
    win_wall = "left" if rng.random() < 0.5 else "right"
    other = "right" if win_wall == "left" else "left"
    m_frame = b.material(Material("frame", solid(lin(0.25, 0.18, 0.1), nz, 0.1, 20.0)))
    window(b, rng, room, win_wall, m_white)
    paintings(b, nz, rng, room, other, m_frame)
    light = ceiling_lamp(b, nz, rng, room, m_frame)
    return Layout(camera=room.camera, support=room.top_c, light=light)


def _room_frame(rng: np.random.Generator, fov_x_deg: float, kitchen: bool) -> Room:
    """Draws the room's size, the camera and the support's placement in front of it."""
    W = rng.uniform(4.6, 5.6)
    D = rng.uniform(5.6, 6.6)
    Hc = rng.uniform(2.6, 2.9)
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
    target = (
        tc + np.array([0, top_h, 0]) + rng.uniform(-0.06, 0.06) * np.array([math.cos(heading), 0, -math.sin(heading)])
    )
    camera = camera_pose(cam, target, fov_x_deg, math.radians(rng.uniform(-1.5, 1.5)), top_h, tdist)
    return Room(W, D, Hc, kitchen, tc, top_h, t_yaw, tlen, tdep, camera)


def _shell(b: Builder, nz: Noise, rng: np.random.Generator, room: Room) -> tuple[np.ndarray, np.ndarray, int]:
    """Floor, ceiling, papered walls (normals inward) and white baseboards.

    Returns:
        ``(light wood colour, dark wood colour, white paint material)``, reused by the furniture.
    """
    W, D, Hc, kitchen = room.W, room.D, room.Hc, room.kitchen
    x0, x1, z0, z1 = room.x0, room.x1, room.z0, room.z1
    hue = rng.random()
    wall_base = hsv(hue, rng.uniform(0.08, 0.3), rng.uniform(0.7, 0.88))
    wall_stripe = hsv(hue + rng.uniform(-0.1, 0.1), rng.uniform(0.15, 0.4), rng.uniform(0.55, 0.75))
    m_wall = b.material(
        Material("wallpaper", wallpaper(wall_base, wall_stripe, nz, rng.uniform(0.18, 0.35), rng.uniform(0.3, 0.6)))
    )
    m_ceil = b.material(Material("ceiling", solid(lin(0.92, 0.91, 0.88), nz, 0.03)))
    wood_l = hsv(rng.uniform(0.06, 0.1), rng.uniform(0.4, 0.6), rng.uniform(0.55, 0.8))
    wood_d = wood_l * rng.uniform(0.35, 0.55)
    plank_axis = rot_y(0.0 if rng.random() < 0.5 else math.pi / 2)
    if kitchen:
        tc0 = lin(*([rng.uniform(0.75, 0.9)] * 3))
        tc1 = hsv(rng.random(), rng.uniform(0.1, 0.4), rng.uniform(0.25, 0.5))
        m_floor = b.material(
            Material("floor_tiles", tiles(tc0, tc1, lin(0.4, 0.4, 0.38), nz, rng.uniform(0.3, 0.5), True))
        )
    else:
        m_floor = b.material(
            Material(
                "floor_planks",
                planks(wood_l, wood_d, nz, rng.uniform(0.14, 0.22), rng.uniform(1.0, 1.6), wood_d * 0.4),
                axes=plank_axis,
            )
        )
    m_white = b.material(Material("white_paint", solid(lin(0.9, 0.9, 0.88), nz, 0.03)))

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
    return wood_l, wood_d, m_white


def _kitchen_island(b: Builder, nz: Noise, rng: np.random.Generator, room: Room) -> int:
    """The kitchen's support: a marble top on a cabinet block. Returns the cabinet material."""
    tc, top_c, top_h, t_yaw = room.tc, room.top_c, room.top_h, room.t_yaw
    m_marble = b.material(
        Material("marble", marble(lin(0.93, 0.92, 0.9), lin(0.35, 0.36, 0.4), nz), origin=top_c, axes=room.Rt)
    )
    cab_col = hsv(rng.random(), rng.uniform(0.1, 0.5), rng.uniform(0.3, 0.8))
    m_cab = b.material(Material("cabinet", cabinet(cab_col, nz, 0.5, cab_col * 0.4)))
    th = 0.04
    b.box(top_c - [0, th / 2, 0], [room.tlen, th, room.tdep], m_marble, t_yaw)
    b.box(tc + [0, (top_h - th) / 2, 0], [room.tlen - 0.12, top_h - th, room.tdep - 0.2], m_cab, t_yaw)
    return m_cab


def _table(b: Builder, nz: Noise, rng: np.random.Generator, room: Room, wood_l, wood_d) -> None:
    """The living room's support: a wooden table on four legs, with a rug under it."""
    tc, top_c, top_h, t_yaw, tlen, tdep = room.tc, room.top_c, room.top_h, room.t_yaw, room.tlen, room.tdep
    m_table = b.material(
        Material("table_wood", wood(wood_l * 1.05, wood_d * 0.8, nz, rng.uniform(14, 24)), origin=top_c, axes=room.Rt)
    )
    th = 0.035
    b.box(top_c - [0, th / 2, 0], [tlen, th, tdep], m_table, t_yaw)
    b.box(top_c - [0, th + 0.04, 0], [tlen - 0.1, 0.08, tdep - 0.1], m_table, t_yaw)
    for sx in (-1, 1):
        for sz in (-1, 1):
            lc = tc + sx * (tlen / 2 - 0.07) * room.tx + sz * (tdep / 2 - 0.07) * room.tz
            b.box(lc + [0, (top_h - th) / 2, 0], [0.055, top_h - th, 0.055], m_table, t_yaw)
    rcols = [hsv(rng.random(), rng.uniform(0.3, 0.7), rng.uniform(0.3, 0.7)) for _ in range(3)]
    rhx, rhz = tlen / 2 + rng.uniform(0.5, 0.8), tdep / 2 + rng.uniform(0.5, 0.8)
    m_rug = b.material(Material("rug", rug(rcols, nz, rhx, rhz, int(rng.integers(3))), origin=tc, axes=room.Rt))
    b.box(tc + [0, 0.005, 0], [2 * rhx, 0.01, 2 * rhz], m_rug, t_yaw)
