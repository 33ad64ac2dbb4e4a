"""The memory guard's share of the glass object: bytes per face of its mesh, and the faces of a config's object.

The object is built in the scene stage and held by every later one; the warps (and the true render,
and a method that traces its own warps) build Open3D's ray-casting scene of it. Its share of each
stage's peak is :data:`MESH_BYTES_PER_FACE` per face (``F``), times the guard's margin, on top of
the image's (:func:`~snell_bench.experiment.memory.stage_bytes`). Per-ray buffers do not grow with
``F``.

``F`` comes from the config without building the object (:func:`object_faces`): a mesh file's header
or a streamed count (:func:`~snell_bench.scene.mesh_header.mesh_face_count`: PLY, STL, OBJ; other
formats a bound from the file's size), and for a procedural object the count its factory makes
(a sphere of ``subdivisions=5``: 20,480 faces).

Measured: an icosphere (``trimesh.creation.icosphere``, subdivisions 6, 7 and 8: 81,920, 327,680 and
1,310,720 faces, twice as many faces as vertices, as scans and remeshes have) written as PLY, STL and
OBJ, read through :meth:`~snell_bench.scene.objects.GlassObject.from_file` (trimesh's arrays and
caches, the cleaning steps), placed (a copy), and traced by a
:class:`~snell_bench.optics.tracer.SceneTracer` (the ray-casting scene's BVH, the corner normals)
in a fresh process; its peak (``ru_maxrss``) minus the peak just before (the libraries loaded and a
small object traced once), bytes per face:

======  ==========  ========
format  faces       B/face
======  ==========  ========
PLY     81,920      1,901
PLY     327,680     2,224
PLY     1,310,720   2,267
STL     81,920      1,565
STL     327,680     2,385
STL     1,310,720   1,799
OBJ     81,920      1,460
OBJ     327,680     2,125
OBJ     1,310,720   1,800
======  ==========  ========

Mitsuba's copy of the object for the reference (its corners split, its
BVH) peaked lower, at 0.57 to 0.98 kB a face with the object held. :data:`MESH_BYTES_PER_FACE`
lies at or above every measured peak; with the guard's margin of 15 % the estimate is 1.16 to 1.89
times them (a mesh of 5,242,880 faces: 14.5 GB). A vertex that very many faces meet costs its
own faces squared in the corner normals, not the largest valence times every corner.
"""

from __future__ import annotations

import inspect
import logging
import math
from typing import Any

from omegaconf import DictConfig

log = logging.getLogger(__name__)

__all__ = ["MESH_BYTES_PER_FACE", "fitting_faces", "object_faces"]

#: Bytes of host memory per face of the object's mesh, in every stage (module docstring: 1,984 to
#: 2,332 measured, before the guard's margin).
MESH_BYTES_PER_FACE = 2400.0


def _procedural_faces(factory: Any) -> int:
    """Faces of a procedural object's mesh, from its factory's arguments and their defaults (0 for
    a factory not known here)."""
    from snell_bench.scene.objects import GlassObject
    from snell_bench.scene.vessels import glass_of_water

    target = str(factory.get("_target_", ""))
    faces = {
        "snell_bench.scene.objects.GlassObject.sphere": (GlassObject.sphere, lambda a: 20 * 4 ** a["subdivisions"]),
        "snell_bench.scene.objects.GlassObject.cylinder": (GlassObject.cylinder, lambda a: 4 * a["sections"]),
        "snell_bench.scene.objects.GlassObject.pyramid": (GlassObject.pyramid, lambda a: 8),
        "snell_bench.scene.vessels.glass_of_water": (
            glass_of_water,
            lambda a: 16 * a["sections"] * (2 if a["straw"] else 1),
        ),
    }.get(target)
    if faces is None:
        return 0
    fn, count = faces
    args = {k: p.default for k, p in inspect.signature(fn).parameters.items()}
    args.update({k: factory[k] for k in args if k in factory})
    try:
        return int(count({k: int(v) if isinstance(v, (bool, int, float)) else v for k, v in args.items()}))
    except (TypeError, ValueError, KeyError):
        return 0


def object_faces(obj_cfg: DictConfig) -> tuple[int, str, bool]:
    """The faces of the object ``obj_cfg`` builds, without building it (module docstring).

    Args:
        obj_cfg: the cell's ``object`` node.

    Returns:
        ``(faces, what, exact)``: the count (a bound from above where ``exact`` is False), the
        setting it comes from (``object.path=<path>``, ``object=<name>``) and whether it was counted.
        A mesh file that is missing or cannot be read counts 0 (its cell reports it).
    """
    factory = obj_cfg.get("factory") or {}
    if "path" not in factory:
        return _procedural_faces(factory), f"object={obj_cfg.get('name')}", True
    from snell_bench.scene.mesh_header import mesh_face_count
    from snell_bench.utils.paths import data_path

    what = f"object.path={obj_cfg.get('path')}"
    try:
        count = mesh_face_count(data_path(obj_cfg.path, "object.path", "mesh file (.ply/.obj/.glb/.stl)"))
    except (OSError, ValueError, TypeError) as e:
        log.warning("memory guard: %s: %s; its mesh not estimated", what, e)
        return 0, what, True
    return count.faces, what, count.exact


def fitting_faces(peak_without: float, budget: float, bytes_per_face: float) -> int | None:
    """The most faces with which a cell fits ``budget``, or ``None`` if none does.

    Args:
        peak_without: the cell's peak without the object's mesh, bytes.
        budget: bytes.
        bytes_per_face: the estimate's bytes per face, margin included.

    Examples:
        >>> fitting_faces(2e9, 8e9, 1.15 * MESH_BYTES_PER_FACE)
        2173913
    """
    if bytes_per_face <= 0:
        return None
    faces = math.floor((budget - peak_without) / bytes_per_face)
    return faces if faces > 0 else None
