"""What a layout is made of: the camera pose, the layout a layout function returns, the room frame.

Every quantity is in the world frame of the procedural scenes (y up, metres). The indoor kinds
(:mod:`snell_bench.scene.procedural.layouts`, furnished by
:mod:`snell_bench.scene.procedural.furniture`) and the outdoor kind
(:mod:`snell_bench.scene.procedural.outdoor`) build on these types.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from snell_bench.scene.procedural.noise import rot_y
from snell_bench.scene.procedural.shading import Light

__all__ = ["CameraPose", "Layout", "Room", "camera_pose"]


class CameraPose(NamedTuple):
    """A camera without roll: ``position`` (world), heading ``yaw`` about y, downward ``pitch`` (radians)."""

    position: np.ndarray
    yaw: float
    pitch: float


@dataclass
class Layout:
    """What a layout function returns, in the world frame.

    Attributes:
        camera: The camera pose.
        support: A point on the horizontal top of the supporting surface, where an object can
            stand.
        light: The key and ambient light (its ``vector`` in world coordinates).
        env: Radiance of rays that miss every surface, from world directions (``None``: black).
        floor: Height of the floor or ground.
    """

    camera: CameraPose
    support: np.ndarray
    light: Light
    env: Callable[[np.ndarray], np.ndarray] | None = None
    floor: float = 0.0


def camera_pose(
    position, target, fov_x_deg: float, pitch_jitter: float, table_top: float, table_dist: float, offset: float = 0.55
) -> CameraPose:
    """A camera at ``position`` heading (horizontally) towards ``target``.

    It is pitched so that the target appears ``offset`` of the half image height below the centre
    (of a 16:9 image), then by ``pitch_jitter``, and clipped to 10-22 degrees.

    Args:
        position: Camera position (world).
        target: The point to look towards.
        fov_x_deg: Horizontal field of view.
        pitch_jitter: Extra pitch (radians).
        table_top: Height of the target.
        table_dist: Horizontal distance from the camera to the target.
        offset: Where the target appears below the centre, as a fraction of the half height.

    Returns:
        The camera pose.
    """
    C = np.asarray(position, np.float64)
    to = np.asarray(target, np.float64) - C
    yaw = math.atan2(to[0], to[2])
    alpha = math.atan2(C[1] - table_top, table_dist)
    tan_half_v = math.tan(math.radians(fov_x_deg) / 2) * 9.0 / 16.0
    pitch = alpha - math.atan(offset * tan_half_v) + pitch_jitter
    pitch = float(np.clip(pitch, math.radians(10.0), math.radians(22.0)))
    return CameraPose(C, yaw, pitch)


@dataclass
class Room:
    """The frame of an indoor scene: the room box, the support (table or island) and the camera.

    Attributes:
        W: Width along x; the room spans ``x0 = -W/2`` to ``x1 = W/2``.
        D: Depth along z; the room spans ``z0 = 0`` to ``z1 = D`` (the far wall).
        Hc: Ceiling height.
        kitchen: Whether this is the kitchen (an island instead of a table).
        tc: Centre of the support on the floor.
        top_h: Height of the support's top.
        t_yaw: Yaw of the support.
        tlen: Length of the support along its local x.
        tdep: Depth of the support along its local z.
        camera: The camera pose.
        x0, x1, z0, z1: The room's extent (derived).
        Rt: Rotation of the support's yaw; ``tx``, ``tz`` are its x and z columns (derived).
        top_c: Centre of the support's top (derived).
    """

    W: float
    D: float
    Hc: float
    kitchen: bool
    tc: np.ndarray
    top_h: float
    t_yaw: float
    tlen: float
    tdep: float
    camera: CameraPose

    def __post_init__(self) -> None:
        self.x0, self.x1, self.z0, self.z1 = -self.W / 2, self.W / 2, 0.0, self.D
        self.Rt = rot_y(self.t_yaw)
        self.tx, self.tz = self.Rt[:, 0], self.Rt[:, 2]
        self.top_c = self.tc + np.array([0, self.top_h, 0])  # centre of the support's top
