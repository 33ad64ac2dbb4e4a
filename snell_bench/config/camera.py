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

    ``scene.intrinsics`` ``[fx, fy, cx, cy]`` imply the horizontal field of view
    ``2 atan(W / (2 fx))`` (:func:`implied_fov_deg`, ``W`` the image's width in the pixels of
    ``fx``), held to the same range (:func:`intrinsics_problem`).
"""

from __future__ import annotations

import math

__all__ = [
    "MAX_FOV_DEG",
    "edge_stretch",
    "focal_for_fov",
    "fov_problem",
    "implied_fov_deg",
    "intrinsics_problem",
    "min_fov_deg",
]

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


def implied_fov_deg(fx: float, width: float) -> float:
    """The horizontal field of view (degrees) of a pinhole camera whose focal length is ``fx``
    pixels over an image ``width`` pixels wide: ``2 atan(W / (2 fx))``.

    Examples:
        >>> round(implied_fov_deg(320.0, 640), 6)
        90.0
    """
    return math.degrees(2.0 * math.atan(float(width) / (2.0 * float(fx))))


def focal_for_fov(fov_deg: float, width: float) -> float:
    """The focal length in pixels that gives an image ``width`` pixels wide this horizontal field
    of view (degrees, in (0, 180)): the inverse of :func:`implied_fov_deg`.

    Examples:
        >>> round(focal_for_fov(90.0, 640), 6)
        320.0
    """
    return float(width) / (2.0 * math.tan(math.radians(float(fov_deg)) / 2.0))


def _too_wide(fov: float) -> str:
    """Why a horizontal field of view above :data:`MAX_FOV_DEG` is refused."""
    why = (
        f"a pinhole camera this wide stretches its frame's edges {edge_stretch(fov):.3g} times against the centre"
        if fov < 180.0
        else "a pinhole camera sees less than 180 degrees across"
    )
    return f"{why}, beyond any rectilinear lens (the widest see about 120 degrees)"


#: What a refusal of the object's fit says happens in too narrow a field of view.
_TOO_NARROW = (
    "the object (that times its distance wide) would be wider than the frame, covering every pixel with nothing "
    "around it to refract"
)


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
        return (
            f"scene.fov_deg={fov_deg!r}: must be at most {MAX_FOV_DEG:g} degrees: {_too_wide(fov)}; a wider photo "
            "is a fisheye: undistort it and give scene.intrinsics=[fx,fy,cx,cy], or e.g. scene.fov_deg=60"
        )
    if relative_size is not None and relative_size > 0:
        lowest = min_fov_deg(relative_size)
        if fov < lowest:
            fits = 2.0 * math.tan(math.radians(fov) / 2.0)
            return (
                f"scene.fov_deg={fov_deg!r}: at object.relative_size={relative_size:g} {_TOO_NARROW}; it fits from "
                f"scene.fov_deg={math.ceil(lowest * 10) / 10:g} (2 atan(relative_size / 2)): fix "
                f"the field of view, or make the object smaller, e.g. object.relative_size={0.5 * fits:.2g}"
            )
    return None


def intrinsics_problem(
    intrinsics: list[float], width: int, relative_size: float | None, image: str = "scene.image"
) -> str | None:
    """Why the horizontal field of view that ``scene.intrinsics`` imply (:func:`implied_fov_deg`)
    is outside the range of ``scene.fov_deg`` (:func:`fov_problem`), or ``None``.

    Args:
        intrinsics: ``[fx, fy, cx, cy]``, finite, ``fx > 0``.
        width: the image's width in the pixels of ``fx``: the photo file's (as stored), or
            ``scene.width`` for a generated scene.
        relative_size: as :func:`fov_problem`.
        image: how the message names the image (``scene.image``, ``scene.width``).

    Returns:
        One line naming ``scene.intrinsics``, the implied angle, the reason and an ``fx`` that fits.

    Examples:
        >>> intrinsics_problem([525.0, 525.0, 319.5, 239.5], 640, 0.25) is None
        True
        >>> line = intrinsics_problem([0.28, 0.28, 319.5, 239.5], 640, 0.25)
        >>> "implies a horizontal field of view of 179.9 degrees" in line, line.split(": set ")[-1]
        (True, 'scene.intrinsics with fx >= 85.75, e.g. fx=554.3 for 60 degrees')
    """
    fx, width = float(intrinsics[0]), int(width)
    fov = implied_fov_deg(fx, width)
    shown = (
        f"scene.intrinsics={list(intrinsics)!r}: fx={fx:g} over the {width}-pixel width of {image} implies a "
        f"horizontal field of view of {fov:.4g} degrees (2 atan(W / (2 fx)))"
    )
    usual = f"e.g. fx={focal_for_fov(60.0, width):.4g} for 60 degrees"
    if fov > MAX_FOV_DEG:
        return (
            f"{shown}, more than {MAX_FOV_DEG:g}: {_too_wide(fov)}; fx is in pixels of that image (scale it if "
            "it was calibrated at another resolution; a wider photo is a fisheye: undistort it first): set "
            f"scene.intrinsics with fx >= {math.ceil(focal_for_fov(MAX_FOV_DEG, width) * 100) / 100:g}, {usual}"
        )
    if relative_size is not None and relative_size > 0:
        lowest = min_fov_deg(relative_size)
        if fov < lowest:
            fits = 2.0 * math.tan(math.radians(fov) / 2.0)
            return (
                f"{shown}: at object.relative_size={relative_size:g} {_TOO_NARROW}; it fits with fx <= "
                f"{math.floor(focal_for_fov(lowest, width) * 100) / 100:g} ({lowest:.1f} degrees): fix fx (pixels of "
                f"that image), {usual}, or make the object smaller, e.g. object.relative_size={0.5 * fits:.2g}"
            )
    return None
