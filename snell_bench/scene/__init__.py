"""Scene geometry: the camera, depth-map meshes, glass objects, placement, procedural scenes."""

from snell_bench.scene.camera import Camera
from snell_bench.scene.depth_mesh import BackgroundMesh, build_background, depth_to_mesh
from snell_bench.scene.objects import MATERIALS, GlassObject, resolve_ior
from snell_bench.scene.placement import SupportPlane, find_support_plane, place_object

__all__ = [
    "Camera",
    "BackgroundMesh",
    "build_background",
    "depth_to_mesh",
    "MATERIALS",
    "GlassObject",
    "resolve_ior",
    "SupportPlane",
    "find_support_plane",
    "place_object",
]
