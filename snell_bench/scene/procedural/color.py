"""Colour helpers of the procedural scenes: the sRGB transfer function and colour literals."""

from __future__ import annotations

import colorsys

import numpy as np

from snell_bench.imaging.color import linear_to_srgb, srgb_to_linear

__all__ = ["srgb_encode", "srgb_decode", "lin", "hsv"]


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """Encodes linear RGB as sRGB with :func:`snell_bench.imaging.color.linear_to_srgb`.

    Args:
        linear: Linear RGB values of any shape (clipped to ``[0, 1]``).

    Returns:
        The sRGB values as float32, same shape.
    """
    return linear_to_srgb(np.asarray(linear, dtype=np.float32)).astype(np.float32)


def srgb_decode(srgb: np.ndarray) -> np.ndarray:
    """Decodes sRGB to linear RGB with :func:`snell_bench.imaging.color.srgb_to_linear`.

    Args:
        srgb: sRGB values of any shape (clipped to ``[0, 1]``).

    Returns:
        The linear RGB values as float32, same shape.
    """
    return srgb_to_linear(np.asarray(srgb, dtype=np.float32)).astype(np.float32)


def lin(*rgb: float) -> np.ndarray:
    """Converts an sRGB colour literal to linear RGB.

    Args:
        *rgb: The red, green and blue sRGB components in ``[0, 1]``.

    Returns:
        The linear colour, float32 of shape (3,).
    """
    return srgb_decode(np.array(rgb, dtype=np.float32))


def hsv(h: float, s: float, v: float) -> np.ndarray:
    """Converts an HSV colour (components in sRGB space) to linear RGB.

    Args:
        h: Hue in turns; any real number (only ``h % 1`` matters).
        s: Saturation in ``[0, 1]``.
        v: Value in ``[0, 1]``.

    Returns:
        The linear colour, float32 of shape (3,).
    """
    return lin(*colorsys.hsv_to_rgb(h % 1.0, s, v))
