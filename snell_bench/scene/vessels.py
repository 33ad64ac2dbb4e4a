"""Objects of several media built by revolving profiles: a glass of water, with a straw.

Convention:
    - The shells are surfaces of revolution about the object's up axis (trimesh's
      :func:`~trimesh.creation.revolve` of an ``(r, height)`` profile, all with the same number of
      ``sections``, so their rings lie at the same angles); lengths are fractions of the vessel's
      height before :meth:`~snell_bench.scene.objects.GlassObject.nested` objects are brought to the
      canonical frame (y up, bottom centre at the origin, largest side 1).
    - Where shells meet, their surfaces meet along shared rings (the water's surface has a ring
      where it meets the glass's inner wall and each side of the straw's wall; the glass's inner wall
      and the straw's walls have a ring at the water's level), so that every face separates the same
      two media everywhere on it (:func:`~snell_bench.optics.media.interface_faces`, which the
      reference renderer needs).
    - The water overlaps the glass (its side and bottom lie inside the glass's wall and base) and the
      glass and the straw have the higher priority: the priority rule turns the overlap into the
      glass, so glass and water meet without a gap or a doubled surface.
"""

from __future__ import annotations

import numpy as np
import trimesh

from snell_bench.config.materials import CLEAR, Medium, absorption_coefficients

__all__ = ["glass_of_water"]

_Z_TO_Y_UP = np.array([[1, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]], dtype=float)


def _revolve(profile, sections: int) -> trimesh.Trimesh:
    mesh = trimesh.creation.revolve(np.asarray(profile, np.float64), sections=sections)
    if not mesh.is_watertight or mesh.volume <= 0:  # a profile that is not counter-clockwise in (r, height)
        raise ValueError("a vessel profile did not revolve into a closed, outward-facing shell")
    return mesh


def _sigma(absorption) -> tuple[float, float, float]:
    if absorption is None:
        return CLEAR
    return absorption_coefficients(list(absorption["color"]), absorption["distance"])


def _straw(radius: float, wall: float, bottom: float, level: float, top: float, sections: int) -> trimesh.Trimesh:
    """An open tube on the axis from ``bottom`` to ``top``, its walls with a ring at the water's ``level``."""
    r_in = radius - wall
    profile = [(r_in, bottom), (radius, bottom), (radius, level), (radius, top), (r_in, top), (r_in, level)]
    return _revolve([*profile, (r_in, bottom)], sections)


def glass_of_water(
    ior="glass",
    *,
    radius: float = 0.35,
    wall: float = 0.03,
    base: float = 0.08,
    fill: float = 0.7,
    water="water",
    water_absorption: dict | None = None,
    straw: bool = False,
    straw_radius: float = 0.05,
    straw_wall: float = 0.012,
    straw_height: float = 1.3,
    straw_ior="acrylic",
    straw_absorption: dict | None = None,
    sections: int = 128,
):
    """A cylindrical glass (tumbler) of water, optionally with an upright straw in its middle.

    Args:
        ior: the glass's IOR (``object.ior``: the object's own material is the glass's).
        radius: the glass's outer radius, a fraction of its height.
        wall: its wall's thickness (fraction of the height; less than ``radius``).
        base: its base's thickness.
        fill: the water's level, a fraction of the height (above the base, below the rim).
        water: the water's IOR (a material name or a number).
        water_absorption: ``{"color": [r, g, b], "distance": d}`` (Beer–Lambert, as
            ``object.absorption``), or ``None``: clear water.
        straw: add a straw standing upright on the glass's axis, from just above the base to
            ``straw_height`` (above the rim); it is hollow and open, so water fills it below the level.
        straw_radius, straw_wall: the straw's outer radius and wall thickness.
        straw_ior, straw_absorption: its material.
        sections: segments around the axis.

    Returns:
        The :class:`~snell_bench.scene.objects.GlassObject` (canonical frame) of shells glass, water
        (priority 0, the glass 1: the water's overlap with the glass is glass) and the straw
        (priority 1), named ``glass_of_water``.

    Raises:
        ValueError: a dimension that leaves no wall, no water or no room for the straw.

    Examples:
        >>> obj = glass_of_water(straw=True, sections=32)
        >>> [m.ior for m in obj.media], [m.priority for m in obj.media]
        ([1.5, 1.333, 1.49], [1, 0, 1])
    """
    from snell_bench.scene.objects import GlassObject

    inner = radius - wall
    if not (0 < wall < radius and 0 < base < fill < 1.0):
        raise ValueError(
            f"glass_of_water: need 0 < wall ({wall}) < radius ({radius}) and 0 < base ({base}) < fill ({fill}) < 1"
        )
    if straw and not (0 < straw_wall < straw_radius < inner and straw_height > fill):
        raise ValueError(
            f"glass_of_water: the straw needs 0 < straw_wall ({straw_wall}) < straw_radius ({straw_radius}) < the "
            f"glass's inner radius ({inner:g}) and straw_height ({straw_height}) above the water ({fill})"
        )
    if int(sections) != sections or sections < 8:
        raise ValueError(f"glass_of_water: sections must be an integer >= 8, got {sections!r}")
    overlap = 0.5 * min(wall, base)  # how far the water reaches into the glass
    glass = _revolve([(0, 0), (radius, 0), (radius, 1), (inner, 1), (inner, fill), (inner, base), (0, base)], sections)
    surface = [(inner, fill)]
    if straw:
        surface += [(straw_radius, fill), (straw_radius - straw_wall, fill)]
    water_mesh = _revolve(
        [(0, base - overlap), (inner + overlap, base - overlap), (inner + overlap, fill), *surface, (0, fill)], sections
    )
    shells = [(glass, Medium(ior, priority=1)), (water_mesh, Medium(water, _sigma(water_absorption), priority=0))]
    if straw:
        tube = _straw(straw_radius, straw_wall, base + 0.02 * (fill - base), fill, straw_height, sections)
        shells.append((tube, Medium(straw_ior, _sigma(straw_absorption), priority=1)))
    lo = np.min([m.bounds[0] for m, _ in shells], axis=0)
    hi = np.max([m.bounds[1] for m, _ in shells], axis=0)
    to_canonical = np.diag([1.0 / float((hi - lo).max())] * 3 + [1.0]) @ _Z_TO_Y_UP
    for m, _ in shells:
        m.apply_transform(to_canonical)
    return GlassObject.nested(shells, name="glass_of_water", placed=False)
