"""The schema of the scene, the glass object and the warps (``scene``, ``object``, ``warps``): what is traced.

Part of :mod:`snell_bench.config.schema` (its conventions hold here).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Optional

from snell_bench.config.camera import MAX_FOV_DEG, fov_problem
from snell_bench.config.choices import (
    SCENE_KINDS,
    DepthKind,
    Normals,
    Source,
)
from snell_bench.config.errors import Problems, is_number
from snell_bench.config.materials import absorption_problem, ior_out_of_range, ior_range_problem, resolve_ior
from snell_bench.config.names import folder_name_problem
from snell_bench.config.sampler import SCHEDULES

__all__ = ["SceneConfig", "ObjectConfig", "WarpConfig"]


@dataclass
class SceneConfig:
    """Where I⁻, its depth and K come from, and the prompts that describe the scene."""

    #: Scene id (a file in conf/scene/), used in output paths.
    name: str = "living_room"
    #: ``procedural`` (CPU, exact 3-D truth), ``image`` (a photo or RGB-D frame: ``image``, ``depth``,
    #: ``depth_scale``, ``depth_kind``, ``intrinsics`` or ``fov_deg``; without ``depth`` a depth
    #: estimator, ``depth=...``) or ``generated`` (I⁻ generated from ``prompt_minus`` by the model at
    #: seed ``variation``, depth and intrinsics from the depth estimator).
    source: Source = Source.procedural
    #: Procedural stand-in kind (``room``, ``kitchen``, ``outdoor``).
    kind: str = "room"
    #: The variation; the procedural seed is ``seed_offset + variation``.
    variation: int = 0
    seed_offset: int = 0
    #: Whether the paper counts it among the indoor scenes (the ablation grid).
    indoor: bool = True
    #: The licence of I⁻ and its depth, for the benchmark kit's card (``job=export``); ``null``: the
    #: source's own (a procedural scene: snell_bench's MIT; a generated one: the model's terms; a
    #: photo: unknown). Not a result setting.
    licence: Optional[str] = None
    #: Image size of I⁻ (the paper uses 720 x 1280).
    width: int = 1280
    height: int = 720
    #: Sub-pixel samples per side when rendering procedural images (anti-aliasing).
    supersample: int = 2
    #: ``source=image``: the object-free photo I⁻ (PNG/JPEG, any size; centre-cropped to a multiple
    #: of ``model.multiple``, the intrinsics adjusted); relative paths: the working folder, else the
    #: installed package (its ``datasets/``).
    image: Optional[str] = None
    #: ``source=image``: its depth (16-bit PNG or TIFF with ``depth_scale``, ``.npy``, ``.pfm``,
    #: ``.exr``); 0 and NaN are missing depth (unobserved space).
    depth: Optional[str] = None
    #: File units per metre of an integer depth file (5000 for TUM, 1000 for millimetres).
    depth_scale: Optional[float] = None
    #: ``z`` (depth along the optical axis) or ``range`` (distance along the ray).
    depth_kind: DepthKind = DepthKind.z
    #: ``[fx, fy, cx, cy]`` in pixels of the file as stored (turned with the photo when its EXIF
    #: orientation tag turns it), or ``fov_deg`` (horizontal, of the upright photo, square pixels).
    intrinsics: Optional[list] = None
    fov_deg: Optional[float] = None
    #: ``source=image``: resize the photo (Lanczos; its depth by nearest neighbour; the intrinsics
    #: scaled) so that its longer side is at most this many pixels, before it is fitted to the
    #: generator's block; ``null``: the photo's own size. The size used is recorded in the cell.
    max_side: Optional[int] = None
    #: The surface the object stands on, for a segmenter (``segment=sam3``), e.g. "wooden coffee table".
    surface: Optional[str] = "${prompts:${.text},surface,${.prompt_llm}}"
    #: ``source=generated``: denoising steps and schedule of I⁻ (FluxPipeline's default 28 steps).
    steps: int = 28
    schedule: str = "flux"
    #: ``source=generated``: where generated I⁻ are cached (by prompt, size, seed, model); ``null``: off.
    cache_dir: Optional[str] = "runs/cache/scenes"
    #: The approximate up direction in camera coordinates (a camera pitched down by a sees
    #: ``[0, -cos a, -sin a]``); ``null``: the source's own, else ``[0, -1, 0]``.
    up: Optional[list] = None
    #: The prompt with its object phrase marked (``[[with a big glass {object} on top,]]``;
    #: ``{object}`` stands for the object's noun): p, p⁻, p³⁶⁰ and the surface derive from it
    #: (:func:`snell_bench.scene.prompts.decompose`) unless set explicitly below.
    text: str = (
        "A cozy living room with a polished wooden coffee table close to the camera, [[with a big glass {object} on "
        "top,]] surrounded by a beige sofa, a patterned rug, plants, bookshelves, framed wall art, and sunlight "
        "through sheer curtains."
    )
    #: The full prompt p, the object-free p⁻ and the panorama's p³⁶⁰.
    prompt: str = "${prompts:${.text},full,${.prompt_llm}}"
    prompt_minus: str = "${prompts:${.text},minus,${.prompt_llm}}"
    pano_prompt: str = "${prompts:${.text},pano,${.prompt_llm}}"
    #: The object phrase p_obj (``"a big glass {object}"``; relighting's prompt and
    #: ``method.prompt=object`` use it, ``{object}`` replaced by the object's noun).
    object_phrase: str = "${prompts:${.text},object_phrase,${.prompt_llm}}"
    #: A local text-generation model (folder or cached id) that marks the object phrase of a
    #: ``text`` written without ``[[...]]``; ``null``: the phrase must be marked.
    prompt_llm: Optional[str] = None

    def __post_init__(self) -> None:
        p = Problems("scene")
        p.seed("variation", self.variation, " (it seeds the scene and the sampling)")
        p.seed("seed_offset", self.seed_offset)
        # a preview writes into <runs_dir>/preview/<scene.name>-<variation>/<object.name>
        p.append_if(folder_name_problem(self.name, "scene.name", example="living_room", suffix=f"-{self.variation}"))
        if self.source == Source.procedural:
            p.int_at_least("supersample", self.supersample, 1, "", 2)
            if self.kind not in SCENE_KINDS:
                p.append(f"scene.kind={self.kind!r}: no procedural scene of this kind; use one of {list(SCENE_KINDS)}")
        if self.source == Source.generated:
            p.int_at_least("steps", self.steps, 1, "", 28)
            if self.schedule not in SCHEDULES:
                p.append(f"scene.schedule={self.schedule!r} is unknown; use one of {list(SCHEDULES)}")
        if self.fov_deg is not None:
            p.finite(
                "fov_deg", self.fov_deg, fix=f"a horizontal field of view in (0, {MAX_FOV_DEG:g}] degrees, e.g. 60"
            )
            if is_number(self.fov_deg) and math.isfinite(self.fov_deg):
                p.append_if(fov_problem(self.fov_deg, None))  # the narrowest one depends on the object (checks)
        fix = "[fx, fy, cx, cy] in pixels of the image file, e.g. scene.intrinsics=[525,525,319.5,239.5]"
        k = p.numbers("intrinsics", self.intrinsics, 4, optional=True, fix=fix)
        if k is not None and not (k[0] > 0 and k[1] > 0):
            p.append(f"scene.intrinsics={list(self.intrinsics)!r}: the focal lengths fx, fy must be > 0 pixels; {fix}")
        up = p.numbers("up", self.up, 3, optional=True, fix="a direction in camera coordinates, e.g. scene.up=[0,-1,0]")
        if up is not None and not math.hypot(*up) > 0:
            p.append(
                f"scene.up={list(self.up)!r}: a direction cannot be zero; e.g. scene.up=[0,-1,0] (level camera) or "
                "[0,-0.87,-0.5] (30 degrees down)"
            )
        if self.max_side is not None:
            p.int_at_least(
                "max_side", self.max_side, 1, " (pixels of the photo's longer side; null: its own size)", 1280
            )
        p.finite("depth_scale", self.depth_scale, positive=True, optional=True, fix="e.g. 5000 (TUM) or 1000 (mm)")
        p.nonempty_or_null("cache_dir", self.cache_dir, "a folder, or null for no cache")
        p.raise_if_any()


@dataclass
class AbsorptionConfig:
    """The object's absorption (Beer–Lambert), as a colour reached at a thickness: light that
    travels ``distance`` metres inside the material keeps ``color`` of itself (linear RGB), so
    ``σ = -ln(color) / distance`` per channel and a path of length ``L`` keeps ``exp(-σ L)``."""

    #: Linear RGB transmittance after ``distance`` (each in (0, 1]; ``[1, 1, 1]``: clear glass).
    color: list = field(default_factory=lambda: [1.0, 1.0, 1.0])
    #: The thickness in metres at which ``color`` is reached.
    distance: float = 0.1


@dataclass
class ObjectConfig:
    """The glass object and where it stands."""

    name: str = "sphere"
    #: The word for it in the prompt ("a big glass {noun}").
    noun: str = "sphere"
    #: What builds the canonical (unplaced) object: a ``_target_`` node instantiated with
    #: ``ior=object.ior`` (and ``path=`` the resolved ``object.path`` when the node has ``path``),
    #: e.g. ``snell_bench.scene.objects.GlassObject.sphere`` or ``...GlassObject.from_file``.
    factory: Any = None
    #: A mesh file, for factories that read one (relative paths: to the working folder, else to the
    #: installed package, where ``datasets/`` lies).
    path: Optional[str] = None
    #: The mesh file's up axis (``y``, ``z``, ``-z``, ...).
    up_axis: str = "y"
    #: Mesh files: fill simple holes of a mesh that is not watertight (trimesh's ``fill_holes``).
    repair: bool = False
    #: Mesh files: trace a mesh that stays open anyway (rays may leak through its holes); else an
    #: open mesh is an error.
    allow_open: bool = False
    #: The licence of the mesh, for the benchmark kit's card (``job=export``); ``null``: a primitive
    #: of snell_bench (MIT). Not a result setting.
    licence: Optional[str] = None
    #: A material name (glass, water, acrylic, diamond, ...) or a number.
    ior: Any = "glass"
    #: Tinted glass: the colour light keeps after a thickness of the material (clear by default).
    absorption: AbsorptionConfig = field(default_factory=AbsorptionConfig)
    #: ``[lowest, highest]`` IOR accepted for ``object.ior``: a transparent solid or liquid has an
    #: IOR of at least 1 and at most about 3 in visible light. Lower it explicitly for an object
    #: optically thinner than its surroundings (an air bubble in water: ``object.ior=0.75
    #: object.ior_range=[0.5,3]``). Not a result setting.
    ior_range: list = field(default_factory=lambda: [1.0, 3.0])
    #: Mesh files: trace a mesh whose surface crosses itself anyway (its inside is then ill
    #: defined, and rays refract at the inner surfaces); else such a mesh is an error.
    #: Not a result setting.
    allow_self_intersecting: bool = False
    #: Largest bounding-box side in scene units; ``null``: ``relative_size`` x distance.
    size: Optional[float] = None
    relative_size: float = 0.25
    yaw_deg: float = 0.0
    #: A supporting plane counts as horizontal within this angle of the scene's up direction.
    max_tilt_deg: float = 30.0
    #: Where it stands: ``plane`` (a plane fitted to the depth of the surface; bottom centre at the
    #: median of its points, lifted 1e-3 x its size along the normal, facing the camera) or
    #: ``centre_ray`` (the authors': where the ray through the centre of the surface's box meets
    #: the depth mesh, tilted to that triangle's normal, 5 mm up; snell_bench.scene.placement).
    anchor: str = "plane"
    #: Stand on the surface under the object rather than on the plane fitted to it: lifted until
    #: its lower surface clears the depth under it (bumps up to 5 % of its size), as a flat base
    #: stands on a rough table's high points (:func:`snell_bench.scene.resting.rest_on_surface`).
    rest: bool = False

    def __post_init__(self) -> None:
        p = Problems("object")
        if self.anchor not in ("plane", "centre_ray"):
            p.append(f"object.anchor={self.anchor!r}: use plane (a fitted plane) or centre_ray (the authors' rule)")
        fix = "object.size is in scene units (metres); null uses object.relative_size x the distance"
        p.finite("size", self.size, positive=True, optional=True, fix=fix)
        p.finite("relative_size", self.relative_size, positive=True, fix="e.g. object.relative_size=0.25")
        p.finite("yaw_deg", self.yaw_deg, fix="a rotation about the up axis in degrees, e.g. object.yaw_deg=30")
        # 0: no fitted plane is ever exactly level, so none would count as horizontal
        p.finite("max_tilt_deg", self.max_tilt_deg, positive=True, hi=90.0, fix="e.g. object.max_tilt_deg=30")
        p.append_if(folder_name_problem(self.name, "object.name", example="sphere"))  # a preview's folder
        range_problem = ior_range_problem(self.ior_range)
        p.append_if(range_problem)
        try:
            ior = resolve_ior(self.ior)
        except ValueError as e:
            p.append(f"object.ior={self.ior!r}: {e}")
        else:
            if range_problem is None:
                p.append_if(ior_out_of_range(ior, self.ior_range), prefix=f"object.ior={self.ior!r}: ")
        p.append_if(absorption_problem(list(self.absorption.color), self.absorption.distance))
        if str(self.up_axis).lstrip("+-").lower() not in ("x", "y", "z"):
            p.append(f"object.up_axis={self.up_axis!r}: use x, y or z, optionally signed (-z)")
        p.raise_if_any()


@dataclass
class WarpConfig:
    """Ray tracing settings of :func:`snell_bench.optics.compute_warps`."""

    pano_height: int = 1024
    max_bounces: int = 8
    #: ``interpolated`` (smooth, creased at sharp edges), ``face``, or ``radial`` (from each shell's
    #: centre: the exact normals of a sphere or concentric spherical shells, whatever the mesh's
    #: tessellation; wrong for any other shape).
    normals: Normals = Normals.interpolated
    edge_threshold: float = 0.05
    #: Cache folder for warps (content-hashed); ``null`` disables caching.
    cache_dir: Optional[str] = "runs/cache/warps"
    #: Cast primary rays only inside the object's projected bounding box (exact: no pixel outside it
    #: can see the object); ``false`` casts the whole frame.
    roi: bool = True
    #: Treat background farther than the distance at which doing so moves any warp by less than this
    #: many pixels as an environment at infinity (rays reach it by direction); ``null``: exact geometry.
    infinity_tolerance_px: Optional[float] = None
    #: A recipe's own limit on surface interactions per refracted path; it replaces ``max_bounces``
    #: (the presets' cost setting) when set. ``null``: ``max_bounces``. The authors' code: 12.
    recipe_max_bounces: Optional[int] = None
    #: π^R: a refracted ray that ends on the back side of the depth mesh takes the colour of the pixel
    #: there, and π⁻¹'s occlusion test accepts either side (the authors' code); ``false``: unobserved.
    back_faces: bool = False
    #: π^-R looks the panorama up towards the mirror ray's end point seen from the panorama centre
    #: (parallax, occlusion-tested); ``false``: by the mirror ray's direction alone (the authors' code).
    reflection_parallax: bool = True
    #: Add 0.5 px to the source coordinates of every perspective map (π^R, the reflection warp, π) and
    #: keep sources in [0, W - 1) x [0, H - 1): what the authors' pixel-edge coordinates read by
    #: ``grid_sample(align_corners=True)`` sample.
    half_pixel_shift: bool = False
    #: The panorama's centre: ``bbox`` (the object's bounding-box centre) or ``centroid`` (the
    #: area-weighted centroid of its surface, trimesh's ``centroid``: the authors' code).
    pano_center: str = "bbox"
    #: The panorama's axes: ``level`` (gravity-aligned with the scene's up, its centre column along
    #: the camera's horizontal forward) or ``camera`` (the camera's own axes: the authors' code).
    pano_axes: str = "level"

    def __post_init__(self) -> None:
        p = Problems("warps")
        p.int_at_least("pano_height", self.pano_height, 2, "", 1024)
        p.int_at_least("max_bounces", self.max_bounces, 1, "", 8)
        if self.recipe_max_bounces is not None:
            p.int_at_least("recipe_max_bounces", self.recipe_max_bounces, 1, " or null (max_bounces)", 12)
        if self.pano_center not in ("bbox", "centroid"):
            p.append(f"warps.pano_center={self.pano_center!r}: use bbox or centroid")
        if self.pano_axes not in ("level", "camera"):
            p.append(f"warps.pano_axes={self.pano_axes!r}: use level or camera")
        p.finite("edge_threshold", self.edge_threshold, positive=True, fix="e.g. warps.edge_threshold=0.05")
        p.finite("infinity_tolerance_px", self.infinity_tolerance_px, positive=True, optional=True, fix="e.g. 0.5")
        p.nonempty_or_null("cache_dir", self.cache_dir, "a folder, or null for no cache")
        p.raise_if_any()
