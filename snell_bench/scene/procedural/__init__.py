"""Procedural scenes: parametric, textured 3-D scenes with exactly known geometry.

A :class:`ProceduralScene` stands in for "text-to-image model + monocular depth": it renders an
object-free image I⁻ of a scene, its *exact* depth and intrinsics, and 360° panoramas from any
point, all from one radiance field, :meth:`ProceduralScene.radiance`.  A scene is identified by
its ``kind`` (one of :data:`SCENE_KINDS`) and an integer ``seed``; the same pair always gives
bit-identical renders.

Conventions:
    - **Frame.** Every input and output is in the *camera frame* of the scene's perspective
      camera (OpenCV: camera at the origin, x right, y down, z forward; see
      :mod:`snell_bench.scene.camera`). Each scene is built in a world frame (y up, metres) and
      transformed into the camera frame once at construction. World up expressed in the camera
      frame is :attr:`ProceduralScene.up`; it is not exactly ``(0, -1, 0)`` because the camera is
      pitched down.
    - **Units.** Metres. Ray parameters ``t`` are Euclidean distances along unit directions;
      depth is the camera-frame z coordinate at pixel centres.
    - **Colour.** :meth:`~ProceduralScene.radiance` returns *linear* RGB radiance, scaled so that
      lit diffuse surfaces lie in ``[0, 1]`` (emitters such as the sun disc may exceed 1). Images
      returned by :meth:`~ProceduralScene.render` and :meth:`~ProceduralScene.render_panorama`
      are the radiance clipped to ``[0, 1]`` (after averaging supersamples in linear space) and
      encoded with the standard sRGB transfer function (:func:`srgb_encode`), float32 in
      ``[0, 1]``.
    - **Shading** is view-independent: a 3-D point has the same radiance from every viewpoint.
      Diffuse albedo (procedural, 3-D textures in world or object-local coordinates) times
      ``ambient + key light · max(0, n·l) · visibility``, with hard shadows from shadow rays,
      plus emissive surfaces (sky dome, windows, lamps) whose radiance is their texture.
    - **Closure.** Each scene is closed (a room with a ceiling, or a 2 km sky dome), so every ray
      cast from a point inside the scene hits something and depth is finite everywhere.

All ray casting goes through one :class:`open3d.t.geometry.RaycastingScene` per scene (built
lazily on first use).

Modules: :mod:`~.scene` (the scene and its renders), :mod:`~.shading` (ray casting, lighting),
:mod:`~.layouts`, :mod:`~.furniture` and :mod:`~.outdoor` (what each kind contains and where),
:mod:`~.frames` (the camera pose, a layout and the room frame they share), :mod:`~.builder` (the
triangle mesh), :mod:`~.textures` (materials), :mod:`~.noise` and :mod:`~.color` (helpers).
"""

from snell_bench.scene.procedural.color import srgb_decode, srgb_encode
from snell_bench.scene.procedural.scene import SCENE_KINDS, ProceduralScene, SceneRender

__all__ = [
    "SCENE_KINDS",
    "SceneRender",
    "ProceduralScene",
    "srgb_encode",
    "srgb_decode",
]
