"""The ranges of the camera settings: ``scene.fov_deg``, ``scene.intrinsics``, ``scene.up``.

Convention:
    ``scene.fov_deg`` is the horizontal field of view of a pinhole (rectilinear) camera with square
    pixels, in degrees. Its range follows from two facts:

    - **Widest.** A pinhole camera maps the direction at angle ``t`` off its axis to ``f tan t``, so
      the frame's edge is stretched by ``1 / cos²(fov / 2)`` against its centre: 4x at 120 degrees,
      15x at 150, 130000x at 179. No rectilinear lens sees much more than 120 degrees across (the
      widest full-frame ones, 10-12 mm, about 112-122); a wider photo is a fisheye, whose pixels a
      pinhole model puts in the wrong directions. :data:`MAX_FOV_DEG` keeps a margin above them.
    - **Narrowest.** The object stands on the surface at its default size, ``object.relative_size``
      times its distance ``d`` (``object.size: null``): it spans about ``relative_size`` radians,
      while the frame spans ``2 d tan(fov / 2)`` at that distance. Below
      :func:`min_fov_deg` ``= 2 atan(relative_size / 2)`` the object is wider than the frame: it
      fills every pixel (1 degree: all of them), nothing around it is observed and its refraction
      has nothing of I⁻ to show. With ``object.size`` set the object's angular size is unknown
      before the depth is read, and only ``fov_deg > 0`` is required here.
"""

from __future__ import annotations

import math

__all__ = ["MAX_FOV_DEG", "edge_stretch", "min_fov_deg", "fov_problem"]

#: The widest horizontal field of view (degrees) of ``scene.fov_deg``: the frame's edge is then
#: stretched ``1 / cos²(75°)`` = 14.9 times against its centre (see the module docs).
MAX_FOV_DEG = 150.0


def edge_stretch(fov_deg: float) -> float:
    """How many times a pinhole camera with this horizontal field of view (degrees, < 180)
    magnifies the frame's left and right edges against its centre: ``1 / cos²(fov / 2)`` (the
    derivative of ``f tan t`` at ``t = fov / 2`` over that at 0).

    Examples:
        >>> round(edge_stretch(120.0), 6)
        4.0
    """
    return 1.0 / math.cos(math.radians(float(fov_deg)) / 2.0) ** 2


def min_fov_deg(relative_size: float) -> float:
    """The narrowest horizontal field of view (degrees) in which an object ``relative_size`` times
    its distance wide fits: ``2 atan(relative_size / 2)``.

    Examples:
        >>> round(min_fov_deg(0.25), 2)
        14.25
    """
    return math.degrees(2.0 * math.atan(float(relative_size) / 2.0))


def fov_problem(fov_deg: float, relative_size: float | None) -> str | None:
    """Why ``scene.fov_deg`` (a finite number) is outside the usable range, or ``None``.

    Args:
        fov_deg: the horizontal field of view in degrees.
        relative_size: ``object.relative_size`` when the object's size follows it
            (``object.size: null``), else ``None`` (no lower bound but 0).

    Returns:
        One line naming the key, the value, the reason and the fix.
    """
    fov = float(fov_deg)
    if fov <= 0:
        return f"scene.fov_deg={fov_deg!r}: a field of view is an angle > 0 degrees; e.g. scene.fov_deg=60"
    if fov > MAX_FOV_DEG:
        why = (
            f"a pinhole camera this wide stretches its frame's edges {edge_stretch(fov):.3g} times against the centre"
            if fov < 180.0
            else "a pinhole camera sees less than 180 degrees across"
        )
        return (
            f"scene.fov_deg={fov_deg!r}: must be at most {MAX_FOV_DEG:g} degrees: {why}, beyond any rectilinear lens "
            "(the widest see about 120 degrees); a wider photo is a fisheye: undistort it and give "
            "scene.intrinsics=[fx,fy,cx,cy], or e.g. scene.fov_deg=60"
        )
    if relative_size is not None and relative_size > 0:
        lowest = min_fov_deg(relative_size)
        if fov < lowest:
            fits = 2.0 * math.tan(math.radians(fov) / 2.0)
            return (
                f"scene.fov_deg={fov_deg!r}: at object.relative_size={relative_size:g} the object (that times its "
                f"distance wide) would be wider than the frame, covering every pixel with nothing around it to "
                f"refract; it fits from scene.fov_deg={math.ceil(lowest * 10) / 10:g} (2 atan(relative_size / 2)): fix "
                f"the field of view, or make the object smaller, e.g. object.relative_size={0.5 * fits:.2g}"
            )
    return None
