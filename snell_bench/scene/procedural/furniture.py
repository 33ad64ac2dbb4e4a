"""The furnishings of the indoor layouts: everything in a room besides its shell and the support.

Each function adds one piece (or one group of pieces) to the builder, drawing its random choices
from the scene's generator; :func:`snell_bench.scene.procedural.layouts.build_room` calls them in
a fixed order.
"""

from __future__ import annotations

import math

import numpy as np

from snell_bench.scene.procedural.builder import Builder
from snell_bench.scene.procedural.color import hsv, lin
from snell_bench.scene.procedural.frames import Room
from snell_bench.scene.procedural.noise import Noise, mix, rot_y
from snell_bench.scene.procedural.shading import Light
from snell_bench.scene.procedural.textures import Material, cabinet, painting, solid, stone, tiles

__all__ = [
    "tabletop_items",
    "chairs",
    "kitchen_counter",
    "bookshelf",
    "sideboard",
    "corner_plant",
    "floor_ball",
    "wall_frame",
    "window",
    "paintings",
    "ceiling_lamp",
]


def tabletop_items(b: Builder, nz: Noise, rng: np.random.Generator, room: Room) -> tuple[int, int]:
    """A stack of cloth-bound books and a vase or fruit bowl on the far corners of the support.

    They stay clear of the support point.

    Returns:
        The ``(cloth, ceramic)`` materials.
    """
    top_c, tlen, tdep, tx, tz, t_yaw = room.top_c, room.tlen, room.tdep, room.tx, room.tz, room.t_yaw
    m_cloth = b.material(Material("cloth", solid(lin(1, 1, 1), nz, 0.1, 20.0)))
    m_ceramic = b.material(Material("ceramic", solid(lin(1, 1, 1), nz, 0.04, 3.0)))
    side = 1 if rng.random() < 0.5 else -1
    corner = top_c + side * (tlen / 2 - 0.2) * tx + (tdep / 2 - 0.17) * tz
    y = 0.0
    for _ in range(int(rng.integers(2, 4))):
        bt = rng.uniform(0.025, 0.05)
        b.box(
            corner + [0, y + bt / 2, 0],
            [rng.uniform(0.18, 0.26), bt, rng.uniform(0.13, 0.18)],
            m_cloth,
            t_yaw + rng.uniform(-0.3, 0.3),
            tint=hsv(rng.random(), rng.uniform(0.4, 0.8), rng.uniform(0.3, 0.8)),
        )
        y += bt
    corner2 = top_c - side * (tlen / 2 - 0.16) * tx + (tdep / 2 - 0.16) * tz
    if room.kitchen:
        m_fruit = b.material(Material("fruit", solid(lin(1, 1, 1), nz, 0.1, 10.0)))
        b.cylinder(corner2, 0.11, 0.05, m_ceramic, top_radius=0.14, tint=hsv(rng.random(), 0.2, 0.85))
        for k in range(4):
            a = k * 1.7
            b.sphere(
                corner2 + [0.06 * math.cos(a), 0.08 + 0.02 * (k == 3), 0.06 * math.sin(a)],
                0.04,
                m_fruit,
                10,
                16,
                tint=[lin(0.8, 0.15, 0.1), lin(0.95, 0.6, 0.1), lin(0.5, 0.75, 0.2), lin(0.9, 0.8, 0.2)][k],
            )
    else:
        vh = rng.uniform(0.18, 0.3)
        b.cylinder(
            corner2,
            rng.uniform(0.05, 0.08),
            vh,
            m_ceramic,
            top_radius=rng.uniform(0.035, 0.06),
            tint=hsv(rng.random(), rng.uniform(0.3, 0.8), rng.uniform(0.4, 0.85)),
        )
    return m_cloth, m_ceramic


def chairs(b: Builder, rng: np.random.Generator, room: Room, m_fabric: int, m_dark_wood: int, fabric_col) -> None:
    """One to three chairs on the far side and at the ends of the table (none in the kitchen)."""
    tc, tlen, tdep, tx, tz, t_yaw = room.tc, room.tlen, room.tdep, room.tx, room.tz, room.t_yaw
    n_ch = 0 if room.kitchen else int(rng.integers(1, 4))
    spots = [(0.0, 1.0), (-1.0, 0.0), (1.0, 0.0)]
    for i in rng.permutation(3)[:n_ch]:
        sx, sz = spots[i]
        cyaw = t_yaw + (math.pi if sz > 0 else (math.pi / 2 if sx < 0 else -math.pi / 2))
        pc = tc + sx * (tlen / 2 + 0.3) * tx + sz * (tdep / 2 + 0.3) * tz
        Rc = rot_y(cyaw)
        b.box(pc + [0, 0.45, 0], [0.44, 0.05, 0.44], m_fabric, cyaw, tint=fabric_col)
        b.box(pc + [0, 0.75, 0] - 0.2 * Rc[:, 2], [0.44, 0.55, 0.04], m_dark_wood, cyaw)
        for lx in (-0.19, 0.19):
            for lz in (-0.19, 0.19):
                b.box(pc + lx * Rc[:, 0] + lz * Rc[:, 2] + [0, 0.215, 0], [0.04, 0.43, 0.04], m_dark_wood, cyaw)


def kitchen_counter(
    b: Builder, nz: Noise, rng: np.random.Generator, room: Room, m_cab: int, m_fabric: int, fabric_col
) -> None:
    """Counter run along the far wall, upper cabinets, backsplash, fridge, and bar stools."""
    W, x0, x1, z1 = room.W, room.x0, room.x1, room.z1
    m_counter = b.material(Material("countertop", stone(lin(0.5, 0.5, 0.5), lin(0.12, 0.12, 0.13), nz, 6.0)))
    sp = hsv(rng.random(), rng.uniform(0.0, 0.3), rng.uniform(0.5, 0.9))
    m_splash = b.material(
        Material("backsplash", tiles(sp, sp * 0.9, lin(0.85, 0.85, 0.85), nz, 0.12, False, axes=(0, 1)))
    )
    m_steel = b.material(Material("steel", solid(lin(0.62, 0.63, 0.65), nz, 0.04, 30.0)))
    b.box([0, 0.44, z1 - 0.31], [W - 0.02, 0.88, 0.6], m_cab)
    b.box([0, 0.9, z1 - 0.31], [W - 0.02, 0.04, 0.62], m_counter)
    b.box([0, 1.2, z1 - 0.005], [W - 0.02, 0.56, 0.01], m_splash)
    b.box([0, 1.85, z1 - 0.18], [W - 0.02, 0.75, 0.35], m_cab)
    fx = x1 - 0.45 if rng.random() < 0.5 else x0 + 0.45
    b.box([fx, 1.0, z1 - 0.36], [0.85, 2.0, 0.7], m_steel)
    n_st = int(rng.integers(2, 4))
    for k in range(n_st):  # bar stools on the far side of the island
        sp_ = room.tc + (room.tdep / 2 + 0.3) * room.tz + (k - (n_st - 1) / 2) * 0.5 * room.tx
        b.cylinder(sp_, 0.02, 0.62, m_steel, 12)
        b.cylinder(sp_ + [0, 0.62, 0], 0.17, 0.05, m_fabric, 24, tint=fabric_col)


def bookshelf(b: Builder, rng: np.random.Generator, room: Room, m_dark_wood: int, m_cloth: int) -> int:
    """A bookshelf with four rows of books against the far wall, left or right of centre.

    Returns:
        The side it stands on: -1 (left) or 1 (right).
    """
    W, z1 = room.W, room.z1
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
                b.box(
                    [xb + wb / 2, ys + 0.0125 + hb / 2, zc + 0.02],
                    [wb, hb, rng.uniform(0.18, 0.24)],
                    m_cloth,
                    tint=hsv(rng.random(), rng.uniform(0.3, 0.8), rng.uniform(0.2, 0.8)),
                )
            xb += wb + 0.002
    return bs_side


def sideboard(
    b: Builder,
    nz: Noise,
    rng: np.random.Generator,
    room: Room,
    bs_side: int,
    m_dark_wood: int,
    m_ceramic: int,
    m_pot: int,
    m_leaf: int,
) -> None:
    """A sideboard against the far wall, opposite the bookshelf (``bs_side``), with a vase and a plant."""
    W, z1 = room.W, room.z1
    sw, sh = rng.uniform(1.0, 1.5), rng.uniform(0.7, 0.9)
    sx_ = -bs_side * rng.uniform(0.18, 0.28) * W
    cab_col = hsv(rng.random(), rng.uniform(0.1, 0.5), rng.uniform(0.3, 0.8))
    m_cab = b.material(Material("cabinet", cabinet(cab_col, nz, sw / 3, cab_col * 0.4)))
    b.box([sx_, sh / 2 + 0.08, z1 - 0.25], [sw, sh, 0.45], m_cab)
    for lx in (-1, 1):
        b.box([sx_ + lx * (sw / 2 - 0.05), 0.04, z1 - 0.25], [0.04, 0.08, 0.4], m_dark_wood)
    b.cylinder(
        [sx_ + sw / 4, sh + 0.08, z1 - 0.25],
        0.07,
        0.32,
        m_ceramic,
        top_radius=0.045,
        tint=hsv(rng.random(), rng.uniform(0.2, 0.7), rng.uniform(0.5, 0.9)),
    )
    b.cylinder([sx_ - sw / 4, sh + 0.08, z1 - 0.25], 0.08, 0.15, m_pot)
    b.rock([sx_ - sw / 4, sh + 0.08 + 0.3, z1 - 0.25], [0.2, 0.2, 0.2], m_leaf, rng, nz)


def corner_plant(b: Builder, nz: Noise, rng: np.random.Generator, room: Room, m_pot: int, m_leaf: int) -> None:
    """A potted plant near one of the far corners."""
    pcx = room.x0 + 0.35 if rng.random() < 0.5 else room.x1 - 0.35
    pcz = room.z1 - rng.uniform(0.35, 1.8)
    ph_ = rng.uniform(0.35, 0.5)
    b.cylinder([pcx, 0, pcz], 0.2, ph_, m_pot, top_radius=0.24)
    for k in range(3):
        b.rock(
            [pcx + rng.uniform(-0.1, 0.1), ph_ + 0.25 + 0.3 * k, pcz + rng.uniform(-0.1, 0.1)],
            [0.32 - 0.06 * k] * 3,
            m_leaf,
            rng,
            nz,
        )


def floor_ball(b: Builder, rng: np.random.Generator, room: Room) -> None:
    """A striped ball on the floor behind the support."""
    x0, x1, z1 = room.x0, room.x1, room.z1
    ball_c = np.array([rng.uniform(x0 + 0.6, x1 - 0.6), 0.0, rng.uniform(room.tc[2] + room.tdep / 2 + 0.8, z1 - 0.8)])
    br = rng.uniform(0.12, 0.2)
    ball_c[1] = br
    stripe_cols = np.stack([hsv(rng.random(), 0.8, 0.9) for _ in range(3)] + [lin(0.95, 0.95, 0.95)])

    def ball(p, n):
        k = np.floor((np.arctan2(p[:, 2], p[:, 0]) / (2 * np.pi) + 0.5) * 8).astype(np.int64) % 4
        return stripe_cols[k]

    m_ball = b.material(Material("ball", ball, origin=ball_c))
    b.sphere(ball_c, br, m_ball, 16, 32)


def wall_frame(room: Room, wall: str, u: float, y: float) -> tuple[np.ndarray, np.ndarray]:
    """A frame on a wall of the room.

    Args:
        room: The room.
        wall: ``"far"``, ``"left"`` or ``"right"``.
        u: Position along the wall (x for the far wall, z for the side walls).
        y: Height.

    Returns:
        ``(origin, axes)``: axes columns are x along the wall (to the right seen from inside), y up
        and z out of the wall into the room.
    """
    if wall == "far":
        return np.array([u, y, room.z1]), np.stack([[1, 0, 0], [0, 1, 0], [0, 0, -1]], 1).astype(float)
    if wall == "left":
        return np.array([room.x0, y, u]), np.stack([[0, 0, 1], [0, 1, 0], [1, 0, 0]], 1).astype(float)
    return np.array([room.x1, y, u]), np.stack([[0, 0, -1], [0, 1, 0], [-1, 0, 0]], 1).astype(float)


def window(b: Builder, rng: np.random.Generator, room: Room, wall: str, m_white: int) -> None:
    """An emissive window (sky over hills) with a white frame and mullions on ``wall``."""
    sky_top = lin(0.45, 0.65, 0.95)
    sky_bot = lin(0.92, 0.95, 1.0)
    win_w, win_h = rng.uniform(1.0, 1.5), rng.uniform(1.1, 1.4)
    wu = rng.uniform(2.4, room.D - 1.2)
    wy = rng.uniform(0.9, 1.1)
    o, A = wall_frame(room, wall, wu, wy)
    o = o - A[:, 0] * win_w / 2

    def view(p, n):
        v = np.clip(p[:, 1] / win_h, 0, 1)
        c = mix(sky_bot, sky_top, v)
        hills = v < 0.22 + 0.06 * np.sin(p[:, 0] * 5.0 + 1.3) + 0.03 * np.sin(p[:, 0] * 13.0)
        c[hills] = lin(0.55, 0.7, 0.5)
        return c * 1.0

    m_win = b.material(Material("window", view, emissive=True, casts_shadow=False, origin=o, axes=A))
    P = [
        o + A[:, 2] * 0.004 + A[:, 0] * a_ + A[:, 1] * c_ for a_, c_ in ((0, 0), (win_w, 0), (win_w, win_h), (0, win_h))
    ]
    b.quad(*P, m_win)
    for a_, c_, sa, sc in (
        (win_w / 2, 0, win_w + 0.1, 0.06),
        (win_w / 2, win_h, win_w + 0.1, 0.06),
        (0, win_h / 2, 0.06, win_h),
        (win_w, win_h / 2, 0.06, win_h),
        (win_w / 2, win_h / 2, 0.04, win_h),
        (win_w / 2, win_h * 0.6, win_w, 0.04),
    ):
        ctr = o + A[:, 0] * a_ + A[:, 1] * c_ + A[:, 2] * 0.03
        size = np.abs(A[:, 0]) * sa + np.abs(A[:, 1]) * sc + np.abs(A[:, 2]) * 0.05
        b.box(ctr, size, m_white)


def paintings(b: Builder, nz: Noise, rng: np.random.Generator, room: Room, other: str, m_frame: int) -> None:
    """Framed paintings: two on the far wall and one on the wall ``other`` (kitchen: only that one)."""
    W, D, kitchen = room.W, room.D, room.kitchen
    hung = [("far", rng.uniform(-0.35, 0.35) * W)]
    if not kitchen:
        hung += [
            ("far", hung[0][1] + (1 if hung[0][1] < 0 else -1) * rng.uniform(1.0, 1.5)),
            (other, rng.uniform(2.0, D - 1.0)),
        ]
    else:
        hung = [(other, rng.uniform(2.0, D - 1.0))]
    for k, (wall, u) in enumerate(hung):
        pw_, ph2 = rng.uniform(0.5, 1.0), rng.uniform(0.4, 0.8)
        py = rng.uniform(1.35, 1.6) if not (kitchen and wall == "far") else 2.3
        o, A = wall_frame(room, wall, u, py)
        o = o - A[:, 0] * pw_ / 2 + A[:, 2] * 0.03
        ctr = o + A[:, 0] * pw_ / 2 + A[:, 1] * ph2 / 2 - A[:, 2] * 0.015
        size = np.abs(A[:, 0]) * (pw_ + 0.08) + np.abs(A[:, 1]) * (ph2 + 0.08) + np.abs(A[:, 2]) * 0.03
        b.box(ctr, size, m_frame)
        m_p = b.material(Material(f"painting_{k}", painting(rng, nz, pw_, ph2), origin=o, axes=A))
        P = [o + A[:, 2] * 0.002 + A[:, 0] * a_ + A[:, 1] * c_ for a_, c_ in ((0, 0), (pw_, 0), (pw_, ph2), (0, ph2))]
        b.quad(*P, m_p)


def ceiling_lamp(b: Builder, nz: Noise, rng: np.random.Generator, room: Room, m_frame: int) -> Light:
    """A glowing globe hanging above the support: the key light (a point light).

    Returns:
        The scene's light, in world coordinates.
    """
    tc, Hc = room.tc, room.Hc
    lp = np.array([tc[0] + rng.uniform(-0.8, 0.8), Hc - rng.uniform(0.45, 0.7), tc[2] + rng.uniform(-0.3, 0.6)])
    warm = rng.uniform(0.0, 0.12)
    m_lamp = b.material(
        Material("lamp", solid(lin(1.0, 0.95 - warm / 2, 0.85 - warm), nz, 0.0), emissive=True, casts_shadow=False)
    )
    b.sphere(lp, 0.09, m_lamp, 10, 20)
    b.cylinder(lp + [0, 0.09, 0], 0.004, Hc - lp[1] - 0.09, m_frame, 8, caps=False)
    d_top = np.linalg.norm(lp - room.top_c)
    inten = rng.uniform(0.65, 0.8) * (d_top**2 + 0.6)
    return Light(
        kind="point",
        vector=lp,
        color=inten * lin(1.0, 0.96 - warm / 2, 0.9 - warm),
        ambient_sky=lin(0.55, 0.55, 0.57) * rng.uniform(0.8, 0.95),
        ambient_ground=lin(0.45, 0.43, 0.41) * rng.uniform(0.75, 0.9),
        falloff=0.6,
    )
