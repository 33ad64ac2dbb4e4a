"""Image-space operations: equirectangular panoramas (and, later, colour, pyramids, blending)."""

from snell_bench.imaging.equirect import (
    PanoramaCamera,
    direction_to_equirect,
    equirect_grid,
    equirect_to_direction,
)

__all__ = ["PanoramaCamera", "direction_to_equirect", "equirect_grid", "equirect_to_direction"]
