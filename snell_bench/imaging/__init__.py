"""Image-space operations: equirectangular panoramas, pyramids and pyramid warping, blending
(detail-preserving average, Fresnel combination)."""

from snell_bench.imaging.blend import blend_pyramids, detail_preserving_average, fresnel_combine
from snell_bench.imaging.equirect import (
    PanoramaCamera,
    direction_to_equirect,
    equirect_grid,
    equirect_to_direction,
)
from snell_bench.imaging.pyramid import collapse, gaussian_pyramid, laplacian_pyramid, lod_warp, pyramid_warp

__all__ = [
    "PanoramaCamera",
    "direction_to_equirect",
    "equirect_grid",
    "equirect_to_direction",
    "gaussian_pyramid",
    "laplacian_pyramid",
    "collapse",
    "pyramid_warp",
    "lod_warp",
    "detail_preserving_average",
    "blend_pyramids",
    "fresnel_combine",
]
