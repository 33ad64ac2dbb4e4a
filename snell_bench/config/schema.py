"""The structured schema behind ``conf/``: one dataclass per config node, registered with Hydra.

Convention:
    - A string setting with a closed set of values is a :mod:`~snell_bench.config.choices` enum:
      OmegaConf rejects any other value when the config is composed, naming the key and the choices.
    - Each dataclass checks the ranges of its own values in ``__post_init__`` (all lines at once, a
      :class:`~snell_bench.config.errors.ConfigError`); OmegaConf runs it when a node is turned
      into its dataclass (``OmegaConf.to_object``), which :func:`~snell_bench.config.checks.check_config`
      does for every node. Checks across nodes and of files and devices live in
      :mod:`snell_bench.config.checks`.
"""

from __future__ import annotations

import importlib.util
import math
from dataclasses import dataclass, field
from typing import Any, Optional

from omegaconf import MISSING

from snell_bench.config.camera import MAX_FOV_DEG, fov_problem
from snell_bench.config.choices import (
    SCENE_KINDS,
    DepthKind,
    InpaintMask,
    Job,
    Normals,
    OnChange,
    PanoPrior,
    PromptKind,
    Protocol,
    RefMask,
    RefRenderer,
    RefSampler,
    Source,
)
from snell_bench.config.errors import Problems, is_number
from snell_bench.config.materials import ior_out_of_range, ior_range_problem, resolve_ior
from snell_bench.config.names import folder_name_problem
from snell_bench.config.sampler import SCHEDULES, SamplerSettings

__all__ = [
    "Config",
    "SceneConfig",
    "ObjectConfig",
    "WarpConfig",
    "ModelConfig",
    "ModelsConfig",
    "MethodConfig",
    "MethodCostConfig",
    "DepthConfig",
    "SegmentConfig",
    "MetricsConfig",
    "BaselinesConfig",
    "ReferenceConfig",
    "RelightConfig",
    "GridConfig",
    "TradeoffConfig",
    "TrackerConfig",
    "ExportConfig",
    "SamplerSettings",
    "CHECKED_NODES",
]


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
        if str(self.up_axis).lstrip("+-").lower() not in ("x", "y", "z"):
            p.append(f"object.up_axis={self.up_axis!r}: use x, y or z, optionally signed (-z)")
        p.raise_if_any()


@dataclass
class WarpConfig:
    """Ray tracing settings of :func:`snell_bench.optics.compute_warps`."""

    pano_height: int = 1024
    max_bounces: int = 8
    #: ``interpolated`` (smooth, creased at sharp edges) or ``face``.
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


@dataclass
class ModelConfig:
    """The generator backend."""

    #: ``analytic`` (CPU stand-in with an exact velocity), ``tiny_flux`` (random weights, tests),
    #: ``flux`` (FLUX.1-dev through diffusers, GPU).
    name: str = "analytic"
    #: What builds the generator: a ``_target_`` node (conf/model/ interpolates its arguments from
    #: the keys below).
    generator: Any = None
    #: The generator is built from the scene: ``generator`` is also given ``i_minus``,
    #: ``object_mask`` and ``panorama`` (the analytic stand-in's priors).
    from_scene: bool = True
    #: analytic: std of the data distribution around its prior where the model is sure (the room).
    prior_std: float = 0.05
    #: analytic: the same inside the glass, the model's strength: smaller resists synchronisation more.
    glass_std: float = 0.1
    #: The panorama a generator built from the scene starts from (``from_scene``): ``other`` (the
    #: true panorama of another variation of the same procedural scene kind, seen from the same
    #: pose: plausible and wrong, only synchronisation with I⁻ through π corrects it), ``blur``
    #: (the true panorama blurred), ``truth`` (the true panorama: the ground truth of every surface
    #: I⁻ does not show; for tests that need it) or ``observed`` (I⁻ seen through π, smoothly
    #: filled where I⁻ does not look). Sources that cannot render a panorama (photos, generated
    #: scenes) always use ``observed``.
    pano_prior: PanoPrior = PanoPrior.other
    #: flux: a local folder with the diffusers layout, or a model id found in the Hugging Face cache.
    path: Optional[str] = None
    #: flux: ``cuda`` (default when available) or ``cpu``; dtype ``bfloat16`` on GPU by default.
    device: Optional[str] = None
    dtype: Optional[str] = None
    guidance: float = 3.5
    vae_tiling: bool = True
    #: Seed of the model's own construction (analytic latent transform, tiny random weights).
    seed: int = 0
    #: Image sizes must be multiples of this (the generator's latent block: 8 analytic, 16 FLUX).
    multiple: int = 16
    #: What builds the inpainting pipeline of ``method=inpaint`` (a ``_target_`` node: FLUX Fill from
    #: local weights, or the tiny random one); ``null``: the CPU stand-in (the generator's image
    #: pasted into the object region of I⁻, no optics).
    fill: Any = None
    #: What builds the pipelines of the ``external`` baselines instead of loading ``method.model_id``:
    #: a ``_target_`` node called with ``kind=method.architecture`` (``model=tiny_flux``: tiny
    #: random versions of FLUX.2, Qwen-Image and SD3.5, CPU); ``null``: the real weights.
    pipelines: Any = None
    #: What builds the relighter of a method with ``method.relight: true`` (a ``_target_`` node:
    #: FLUX Kontext from local weights, the tiny random one, or the traced-shadow stand-in).
    relighter: Any = None
    #: Build the generator, FLUX Fill and FLUX Kontext with random weights from their published
    #: configurations (no weights read): real shapes and real cost, meaningless pixels. Cells are
    #: marked ``random_weights`` and the reports keep them out of every table (timing, memory plans).
    random_init: bool = False

    def __post_init__(self) -> None:
        p = Problems("model")
        p.int_at_least("multiple", self.multiple, 1, " (the generator's block size)", 16)
        p.seed("seed", self.seed)
        p.finite("prior_std", self.prior_std, positive=True, fix="a standard deviation, e.g. model.prior_std=0.05")
        p.finite("glass_std", self.glass_std, positive=True, fix="a standard deviation, e.g. model.glass_std=0.1")
        p.finite("guidance", self.guidance, lo=0.0, fix="e.g. model.guidance=3.5")
        p.raise_if_any()


@dataclass
class ModelsConfig:
    """The models of a process (:class:`~snell_bench.pipeline.pool.ModelPool`): every model a sweep
    needs is loaded once and kept while the budget allows."""

    #: GiB of model parameters and buffers held at once (``null``: no limit). When the models of a
    #: sweep do not fit together, its cells run model by model (all cells of one model, then the
    #: next), so each model still loads once; a model larger than the budget is loaded alone.
    memory_gb: Optional[float] = None
    #: GB (10^9 bytes) of host memory one cell may use at its peak (estimated from the image and
    #: the panorama sizes before any work; snell_bench/experiment/memory.py): ``null``: this
    #: machine's memory (or its cgroup limit). A cell estimated above it stops the run before any
    #: work, naming the setting that shrinks it (``scene.max_side``, ``scene.width``,
    #: ``warps.pano_height``) with a value that fits; above 75 % of it, a warning.
    host_memory_gb: Optional[float] = None
    #: When a model must make room: ``true`` moves the least recently used model's weights to host
    #: memory (brought back on its next use, far faster than loading it again); ``false`` drops it.
    offload: bool = True

    def __post_init__(self) -> None:
        p = Problems("models")
        p.finite("memory_gb", self.memory_gb, positive=True, optional=True, fix="e.g. models.memory_gb=70")
        p.finite(
            "host_memory_gb", self.host_memory_gb, positive=True, optional=True, fix="e.g. models.host_memory_gb=16"
        )
        p.raise_if_any()


@dataclass
class MethodCostConfig:
    """What ``job=plan`` counts for a diffusers pipeline baseline (``kind: external``): its documented
    figures at 720 x 1280 on an 80 GB GPU (docs/gpu.md). Not a result setting."""

    #: Seconds per image at the pipeline's default steps; ``null``: not documented (no time planned).
    seconds: Optional[float] = None
    #: bfloat16 weights, GB (10⁹ bytes); ``null``: not known.
    weights_gb: Optional[float] = None
    #: The pipeline's default inference steps (``seconds`` scales by ``method.steps`` over these).
    steps: Optional[int] = None

    def __post_init__(self) -> None:
        p = Problems("method.cost")
        p.finite("seconds", self.seconds, positive=True, optional=True, fix="seconds per image, or null")
        p.finite("weights_gb", self.weights_gb, positive=True, optional=True, fix="GB, or null")
        if self.steps is not None:
            p.int_at_least("steps", self.steps, 1, " (the pipeline's default steps)", 28)
        p.raise_if_any()


@dataclass
class MethodConfig:
    """A method: Snellcaster, an ablation, a baseline, images made elsewhere, or a user's method
    (conf/method/, a user's config folder on Hydra's search path, or an installed plugin)."""

    name: str = "snellcaster"
    #: Label in tables and figures.
    label: str = "Snellcaster"
    #: What the method runs, one module of :mod:`snell_bench.methods` each: ``snellcaster`` (the
    #: synchronized sampler), ``t2i`` (the generator alone from p), ``inpaint`` (fill the object
    #: region of I⁻; CPU stand-in without optics), ``external`` (another diffusers pipeline),
    #: ``images`` (score images made anywhere, ``method.images``); or the name of an installed
    #: plugin (the ``snell_bench.methods`` entry points).
    kind: str = "snellcaster"
    #: A user's method class (``my_pkg.methods.MyMethod``, a subclass of
    #: :class:`snell_bench.methods.Method`), built with ``method.params`` as keyword arguments;
    #: ``null``: the class of ``kind``.
    _target_: Optional[str] = None
    #: Keyword arguments of a user's method class (``_target_`` or a plugin's ``kind``).
    params: dict = field(default_factory=dict)
    #: What it needs (``gpu``, ``weights``), for the reader: a method whose pipeline cannot load
    #: here (no CUDA and no ``model.device=cpu``, no weights) is skipped with the reason.
    requires: list = field(default_factory=list)
    #: Overrides of the ``sampler`` node for this method (the ablation switches).
    sampler: dict = field(default_factory=dict)
    #: For ``external`` methods: the diffusers model id (in the Hugging Face cache) or a local folder.
    model_id: Optional[str] = None
    #: For ``external`` methods: the model's architecture (``flux2``, ``qwen_image``, ``sd3``), what
    #: a model's ``pipelines`` builder (the tiny random stand-ins) is asked for.
    architecture: Optional[str] = None
    #: Overrides of the ``warps`` node for this method (e.g. ``infinity_tolerance_px``).
    warps: dict = field(default_factory=dict)
    #: ``external`` and ``inpaint`` pipelines: inference steps and guidance; ``null``: the
    #: pipeline's own default (the ``__call__`` signature's).
    steps: Optional[int] = None
    guidance: Optional[float] = None
    #: The text a pipeline baseline sees: ``full`` (p) or ``object`` (p_obj, the object phrase),
    #: with ``baselines.object_phrase`` in place of p_obj where it is set.
    prompt: PromptKind = PromptKind.full
    #: ``external`` pipelines whose guidance is true classifier-free guidance (``true_cfg_scale``:
    #: Qwen-Image): pass the empty negative prompt that turns it on; false: none (no guidance).
    cfg: bool = True
    #: ``inpaint``: the region repainted: ``object`` (the object's silhouette) or ``box`` (its
    #: bounding box), grown by ``mask_dilate_px`` pixels.
    mask: InpaintMask = InpaintMask.object
    mask_dilate_px: int = 0
    #: Relight the image after sampling (the ``relight`` node; the model's ``relighter``).
    relight: bool = False
    #: ``images``: a folder of one image per (scene, variation, object) group,
    #: ``<folder>/<scene>-<variation>/<object>.png`` (or ``.jpg``), named by the benchmark kit's ids
    #: (``job=export``); or a manifest file (``.csv``, ``.jsonl``, ``.parquet``) with the columns
    #: ``id`` and ``images_column``, paths relative to its folder. Nothing outside that folder is
    #: read. Not a result setting: a cell is known by its image's content.
    images: Optional[str] = None
    #: ``images``: the manifest's column of image paths.
    images_column: str = "image"
    #: ``images``: the benchmark kit the images were made from (``job=export``'s folder); where set,
    #: its schema version and each group's inputs must be this run's (images made for another
    #: camera, object or placement are refused).
    kit: Optional[str] = None
    #: What ``job=plan`` counts for an ``external`` pipeline (not a result setting).
    cost: MethodCostConfig = field(default_factory=MethodCostConfig)

    def __post_init__(self) -> None:
        p = Problems("method")
        p.int_at_least("mask_dilate_px", self.mask_dilate_px, 0, "", 0)
        if self.steps is not None:
            p.int_at_least("steps", self.steps, 1, " (null: the pipeline's default)", 28)
        p.finite("guidance", self.guidance, lo=0.0, optional=True, fix="null: the pipeline's default")
        if not str(self.kind).strip():
            p.append("method.kind='': name what the method runs, e.g. method.kind=snellcaster")
        p.nonempty_or_null("images", self.images, "a folder of <scene>-<variation>/<object>.png or a manifest file")
        p.nonempty_or_null("kit", self.kit, "the folder job=export wrote")
        p.raise_if_any()


@dataclass
class DepthConfig:
    """A monocular depth estimator (conf/depth/): for a photo without depth and for generated scenes."""

    #: ``none`` / ``file`` (the source gives depth), ``moge2``, ``depth_pro``, ``depth_anything_v2``,
    #: ``tiny_depth_pro``, ``tiny_depth_anything`` (random weights, tests).
    name: str = "none"
    #: A local folder with the weights or a model id in the Hugging Face cache (never downloaded).
    path: Optional[str] = None
    #: ``cpu``, ``cuda[:i]`` (must be available) or ``auto`` (CUDA when available).
    device: Optional[str] = "cpu"
    #: What builds it: a ``_target_`` node (``null``: no estimator).
    estimator: Any = None
    #: moge2: cut depth edges, NaN where a pixel's 3 x 3 depth spread exceeds this fraction of its
    #: depth (MoGe's rule; the authors: 0.1); ``null``: keep every pixel the model's mask keeps.
    edge_rtol: Optional[float] = None


@dataclass
class SegmentConfig:
    """Where the object stands (conf/segment/): ``ransac`` (a horizontal plane near the image centre),
    ``sam3`` (the surface ``scene.surface`` names, segmented by SAM 3), ``mask`` (a mask file)."""

    name: str = "ransac"
    path: Optional[str] = None
    #: ``segment=mask``: a PNG of the image's size (after its centre crop), nonzero on the surface.
    mask: Optional[str] = None
    #: ``cuda`` or ``cpu``; ``null``: CUDA when available, else the CPU.
    device: Optional[str] = None
    #: sam3: the score an instance needs; the region is the union of the instances above it.
    threshold: float = 0.5
    #: sam3: which instances above ``threshold`` make the region: ``union`` (all), ``best`` (the
    #: highest score) or ``first`` (the first in SAM 3's query order, the authors').
    instance: str = "union"
    #: What builds it: a ``_target_`` node (``null``: RANSAC only).
    segmenter: Any = None

    def __post_init__(self) -> None:
        p = Problems("segment")
        p.finite("threshold", self.threshold, lo=0.0, hi=1.0, fix="a score, e.g. segment.threshold=0.5")
        if self.instance not in ("union", "best", "first"):
            p.append(f"segment.instance={self.instance!r}: use union, best or first")
        p.raise_if_any()


@dataclass
class MetricsConfig:
    """How images are scored; scorers that need weights read them from these local files (never
    downloaded)."""

    #: ``paper`` (as the paper's text says: grayscale, the generated image's histogram matched onto
    #: the reference's values inside the mask, masked PSNR / MAE on the matched grayscale; LPIPS
    #: (VGG) of the RGB images as they are, its spatial map averaged over the mask) or ``authors``
    #: (as the authors' released evaluation does: the histogram matched in shape but rescaled to the
    #: generated image's own range, LPIPS on RGB with both inputs multiplied by the mask, and
    #: ``lpips_box``).
    protocol: Protocol = Protocol.paper
    #: The files scored: ``png`` (the images as generated and rendered, lossless) or ``jpeg`` (the
    #: authors' eval/eval.py: the generated image as a PIL JPEG of quality 75, the reference of
    #: quality 95, the mask of quality 75 read back ``>= 0.5``; every metric sees them).
    files: str = "png"
    #: ``lpips_box`` (``protocol=authors``): its crop in ``signed`` [-1, 1], the range lpips reads
    #: (eval/eval.py), or ``unit`` [0, 1] read as [-1, 1] (eval/masked_metrics.py).
    lpips_box_range: str = "signed"
    #: The text CLIP and ImageReward score against: ``full`` (p) or ``object`` (p_obj).
    clip_text: PromptKind = PromptKind.full
    #: A YAML or JSON file ``{scene name: text}`` (``{object}``: the object's noun): CLIP and
    #: ImageReward score each scene it lists against its text instead (e.g. the per-scene prompts of
    #: the authors' eval/eval.py); ``null``: ``clip_text``.
    clip_prompts: Optional[str] = None

    #: torchvision VGG16 state dict for LPIPS (e.g. vgg16-397923af.pth).
    lpips_weights: Optional[str] = None
    #: open_clip ViT-B-16 weights file.
    clip_weights: Optional[str] = None
    #: A python executable of a separate environment with image-reward installed.
    image_reward_python: Optional[str] = None
    #: Users' metrics scored after the built-in ones and shown in every table: names of installed
    #: metrics (the ``snell_bench.metrics`` entry points) or dotted paths to a
    #: :class:`~snell_bench.metrics.registry.MetricSpec` (``my_pkg.metrics:SSIM``).
    extra: list = field(default_factory=list)
    #: Score each image as its file holds it: the 8-bit values ``image.png`` stores, for every
    #: method and for images made anywhere (``method=images``), so a saved image re-scores to the
    #: same number; false: the sampler's float image (what cells recorded before this key).
    score_file: bool = True

    def __post_init__(self) -> None:
        p = Problems("metrics")
        if self.files not in ("png", "jpeg"):
            p.append(f"metrics.files={self.files!r} is unknown: use png (lossless) or jpeg (the authors' files)")
        if self.lpips_box_range not in ("signed", "unit"):
            p.append(
                f"metrics.lpips_box_range={self.lpips_box_range!r} is unknown: use signed ([-1, 1], eval/eval.py) "
                "or unit ([0, 1], eval/masked_metrics.py)"
            )
        p.nonempty_or_null("clip_prompts", self.clip_prompts, "a YAML or JSON file {scene name: text}")
        p.raise_if_any()


@dataclass
class BaselinesConfig:
    """Settings of the baselines that the method files interpolate (``${baselines.<key>}``), so
    that a recipe, which cannot address one method's node, sets them."""

    #: The object phrase the baselines' prompts name: ``null``: the scene's own p_obj ("a big glass
    #: {object}"); a text (``{object}``: the object's noun) replaces it in p (text-to-image) and is
    #: the inpainting prompt (the authors: "a solid transparent glass {object}").
    object_phrase: Optional[str] = None
    #: ``method=t2i`` (FLUX alone): denoising steps; ``null``: ``sampler.steps`` (the paper's T).
    flux_steps: Optional[int] = None
    #: ``method=inpaint`` (FLUX Fill): steps and guidance; ``null``: the pipeline's defaults (50, 30).
    fill_steps: Optional[int] = None
    fill_guidance: Optional[float] = None
    #: ``method=qwen_image``: the model (the paper names Qwen-Image; the authors run Qwen-Image-2512).
    qwen_model_id: str = "Qwen/Qwen-Image"
    #: ``method=qwen_image``: classifier-free guidance on (the empty negative prompt " " passed) or
    #: off (no negative prompt: the pipeline skips its ``true_cfg_scale``, as the authors call it).
    qwen_cfg: bool = True

    def __post_init__(self) -> None:
        p = Problems("baselines")
        for name, example in (("flux_steps", 28), ("fill_steps", 30)):
            if getattr(self, name) is not None:
                p.int_at_least(name, getattr(self, name), 1, " (null: the default)", example)
        p.finite("fill_guidance", self.fill_guidance, lo=0.0, optional=True, fix="null: the pipeline's default")
        p.nonempty_or_null("object_phrase", self.object_phrase, "a phrase, e.g. 'a solid transparent glass {object}'")
        p.nonempty_or_null("qwen_model_id", self.qwen_model_id, "a model id or folder")
        p.raise_if_any()


@dataclass
class ReferenceConfig:
    """The independent reference render (Mitsuba 3, or Blender Cycles as the authors' ``render_gt``)."""

    enabled: bool = True
    #: Samples per pixel of the image pass (both halves together with ``self_noise``); rounded up,
    #: with a warning, to a count the sampler takes: ``orthogonal`` halves are squares of primes, so
    #: 2 p² (8, 18, 50, 98, 242, 338, 578, 1058, ...).
    spp: int = 242
    #: Mitsuba's sampler: ``orthogonal`` (the least noise per second here), ``stratified``,
    #: ``multijitter``, ``ldsampler`` or ``independent``.
    sampler: RefSampler = RefSampler.orthogonal
    #: Samples per pixel of the unobserved pass (only the metric mask depends on it); ``null``: ``spp``.
    unobserved_spp: Optional[int] = 25
    #: Render only the object's rectangle (plus ``crop_margin_px``); the rest is the background seen
    #: directly, pasted (the same as a full-frame render there).
    crop: bool = True
    crop_margin_px: int = 4
    #: Render the image pass in two independent halves and record the reference's self-noise
    #: (``self_noise_db``: the estimated PSNR of the reference against its noise-free limit, the
    #: ceiling of every masked PSNR scored against it).
    self_noise: bool = True
    #: A pixel counts for the metrics if less than this share of its light comes from unobserved space.
    unobserved_threshold: float = 0.05
    #: Also render the full procedural scene with the object (the unmasked second reference).
    true_render: bool = True
    true_spp: int = 4
    #: Bounces of the true render; ``null``: ``warps.max_bounces`` (set it to compare bounce counts).
    true_max_bounces: Optional[int] = None
    #: Include the first-surface (Fresnel) reflection in the reference. ``false``: refraction only,
    #: as the paper's Blender reference and the authors' ``render_gt`` (recipes ``paper`` and
    #: ``authors``); ``true``: the physically complete dielectric (snell_bench's own option).
    reflection: bool = True
    #: The renderer: ``mitsuba`` (Mitsuba 3, the background emitting I⁻, unlit) or ``cycles`` (Blender
    #: Cycles with the authors' ``render_gt`` scene: lit Principled mesh, point light, world colour,
    #: exposure, AgX, JPEG q95; needs ``make setup-cycles``; recipe ``authors``).
    renderer: RefRenderer = RefRenderer.mitsuba
    #: The Python with Blender's ``bpy`` that runs the Cycles render; ``null``: ``.venv-cycles``'s.
    blender_python: Optional[str] = None
    #: Cycles' samples per pixel (adaptive sampling may stop earlier; the authors': 1024).
    cycles_spp: int = 1024
    #: The glass's IOR in the reference and its mask; ``null``: the object's (the authors: 1.5 always).
    ior: Optional[float] = None
    #: The metric mask: ``unobserved`` (object pixels whose light comes from surfaces I⁻ shows, the
    #: paper's definition) or ``authors`` (``render_gt``'s: one refracted ray per pixel centre reaches
    #: the background within 16 hits, small holes filled).
    mask: RefMask = RefMask.unobserved

    def __post_init__(self) -> None:
        p = Problems("reference")
        p.nonempty_or_null("blender_python", self.blender_python, "a Python with bpy")
        p.int_at_least("cycles_spp", self.cycles_spp, 1, "", 1024)
        p.finite("ior", self.ior, lo=1.0, hi=4.0, optional=True, fix="e.g. reference.ior=1.5 (null: the object's)")
        p.int_at_least("spp", self.spp, 1, "", 242)
        if self.unobserved_spp is not None:
            p.int_at_least("unobserved_spp", self.unobserved_spp, 1, "", 25)
        p.int_at_least("crop_margin_px", self.crop_margin_px, 0, "", 4)
        p.int_at_least("true_spp", self.true_spp, 1, "", 4)
        if self.true_max_bounces is not None:
            p.int_at_least("true_max_bounces", self.true_max_bounces, 1, " (null: warps.max_bounces)", 16)
        # a pixel counts when its unobserved share is below the threshold: 0 would leave no pixel to score
        p.finite("unobserved_threshold", self.unobserved_threshold, positive=True, hi=1.0, fix="e.g. 0.05")
        p.raise_if_any()


@dataclass
class RelightConfig:
    """Relighting (the paper's last stage): N candidates from the model's relighter, the one with
    the highest masked PSNR against the un-relit image inside the object's silhouette kept."""

    #: Candidates N (the paper: 20; the authors' code: 3).
    candidates: int = 20
    #: The instruction; ``{object_phrase}`` is p_obj (``scene.object_phrase``).
    prompt: str = "Create soft shadows and caustics under {object_phrase}"
    #: Inference steps and guidance of the relighting pipeline; ``null``: its own default.
    steps: Optional[int] = None
    guidance: Optional[float] = None
    #: A LoRA for the relighting pipeline (a local file or folder, or a Hugging Face id in the local
    #: cache, e.g. the authors' ``relighting-kontext-dev-lora-v3``); ``null``: none.
    lora: Optional[str] = None
    lora_scale: float = 1.0

    def __post_init__(self) -> None:
        p = Problems("relight")
        p.int_at_least("candidates", self.candidates, 1, "", 3)
        if self.steps is not None:
            p.int_at_least("steps", self.steps, 1, " (null: the pipeline's default)", 28)
        p.finite("guidance", self.guidance, lo=0.0, optional=True, fix="null: the pipeline's default")
        p.finite("lora_scale", self.lora_scale, fix="the LoRA's weight, e.g. relight.lora_scale=1 (0 turns it off)")
        p.raise_if_any()


@dataclass
class GridConfig:
    """The cells of an experiment: scenes x variations x objects x methods."""

    scenes: list = field(default_factory=lambda: ["living_room"])
    variations: list = field(default_factory=lambda: [0])
    objects: list = field(default_factory=lambda: ["sphere"])
    methods: list = field(default_factory=lambda: ["snellcaster", "t2i"])
    #: Recompute cells that already finished (else they are skipped).
    recompute: bool = False
    #: A finished cell whose recorded settings differ from this run's (``sampler.steps``,
    #: ``scene.width``, ...): ``error`` (stop before any work, naming the changed keys) or
    #: ``recompute`` (redo those cells with this run's settings).
    on_change: OnChange = OnChange.error
    #: Build the report tables after the sweep.
    report: bool = True
    #: Groups (scene x variation x object) whose inputs worker processes prepare ahead of the group
    #: being sampled: their scene, placement and warps before their cells sample, their references
    #: while they sample, so a grid takes about as long as the slower of sampling and preparing
    #: (benchmarks/bench_overlap.py; snell_bench/experiment/prefetch.py). ``null``: automatic, 2
    #: when the generator samples on CUDA (``model.from_scene`` false, ``model.device`` unset,
    #: ``auto`` or ``cuda[:i]``, and CUDA present), else 0: on a CPU-only machine sampling and
    #: preparation share the cores. 0: every stage in this process, in order. Stages that need a
    #: model (a generated I⁻, a depth estimator, SAM 3) always run in this process. The results are
    #: the same either way (not a result setting).
    prefetch: Optional[int] = None
    #: Worker processes that prepare those inputs (each loads no model; the reference renderer
    #: uses every core in each, so more than one pays only where one worker leaves cores idle).
    workers: int = 1
    #: Split the grid's (scene, variation, object) groups between this many jobs (a Slurm job
    #: array with ``-m hydra/launcher=slurm``): each job computes its own groups, so every group's
    #: shared inputs are computed once in the whole cluster. With ``-m``, ``grid.shards=N`` sweeps
    #: ``grid.shard=range(0,N)`` (Hydra's ``hydra.sweeper.params``, conf/config.yaml).
    shards: int = 1
    #: Which shard this job is (0 .. shards - 1); ``null``: every group.
    shard: Optional[int] = None
    #: How a process claims a cell before computing it: ``flock`` (filelock's ``fcntl.flock`` on
    #: ``<cell>/.lock``; the kernel frees the lock of a dead process), ``lease`` (flufl.lock's
    #: hard-link lease ``<cell>/.lease``, renewed every ``lease_ttl_s / 3`` s and broken 10 s after
    #: it expires: for Lustre without ``flock``, NFS with ``local_lock``, BeeGFS) or ``auto`` (``lease`` where flock raises or the mount keeps it
    #: local to one machine, else ``flock``; snell_bench/utils/locks.py). Every job sharing a
    #: run folder must claim the same way. Not a result setting.
    lock: str = "auto"
    #: Seconds a lease lives without renewal: a cell whose process died on another machine is
    #: free again this long (plus 10 s) after its last renewal (at once on the same machine).
    #: Leases are stamped to the second: keep it >= 3, e.g. >= 30.
    lease_ttl_s: float = 120.0
    #: Exit with status 0 even when cells failed (for sweeps that expect some to fail); else the
    #: run's exit status is non-zero when any cell failed.
    allow_failures: bool = False

    def __post_init__(self) -> None:
        p = Problems("grid")
        p.int_at_least("shards", self.shards, 1, " (jobs the groups are split between)", 2)
        if self.shard is not None:
            p.int_at_least("shard", self.shard, 0, " (this job's shard; null: every group)", 0)
            if isinstance(self.shard, int) and isinstance(self.shards, int) and self.shard >= self.shards:
                p.append(
                    f"grid.shard={self.shard!r}: must be below grid.shards={self.shards}; e.g. grid.shard=0 "
                    "(with -m, grid.shards=N alone runs every shard)"
                )
        if self.lock not in ("auto", "flock", "lease"):
            p.append(f"grid.lock={self.lock!r}: must be one of auto, flock, lease; e.g. grid.lock=lease")
        p.finite("lease_ttl_s", self.lease_ttl_s, positive=True, fix="e.g. grid.lease_ttl_s=120")
        if self.prefetch is not None:
            p.int_at_least("prefetch", self.prefetch, 0, " (groups prepared ahead; null: automatic)", 2)
        p.int_at_least("workers", self.workers, 1, " (worker processes)", 1)
        p.raise_if_any()


@dataclass
class TradeoffConfig:
    """The speed/accuracy sweep (``job=tradeoff``): knobs varied one at a time from the base setting."""

    scenes: list = field(default_factory=lambda: ["living_room", "kitchen"])
    variation: int = 0
    #: An object spec (``sphere`` or ``sphere:1.33``) and a method (conf/method/).
    object: str = "sphere"
    method: str = "snellcaster"
    #: Axis name -> a Hydra sweep override (``"sampler.steps=4,8,12"``: one setting per value), or
    #: a mapping ``label -> [override, ...]`` for knobs that change together (the resolution).
    axes: dict = field(default_factory=dict)
    #: Also score every setting against a converged reference rendered with this many samples per
    #: pixel (one per scene, object and resolution, shared by all settings): fidelity that does not
    #: move with ``reference.spp`` (1058: the paper preset's count); the Pareto front uses it. ``null``: off.
    converged_spp: Optional[int] = 1058
    #: The axes to run (names of ``axes``); ``null``: all of them.
    only: Optional[list] = None
    #: Presets (conf/preset/) measured as extra points of the sweep.
    presets: list = field(default_factory=lambda: ["fast", "balanced", "paper"])
    #: Recompute settings that already finished (else they are reused).
    recompute: bool = False
    #: A finished setting whose recorded config differs from this run's: ``error`` or ``recompute``.
    on_change: OnChange = OnChange.error
    #: Exit with status 0 even when settings failed; else the exit status is 3 when any did.
    allow_failures: bool = False

    def __post_init__(self) -> None:
        p = Problems("tradeoff")
        p.seed("variation", self.variation, " (it seeds the scene and the sampling)")
        if self.converged_spp is not None:
            p.int_at_least("converged_spp", self.converged_spp, 1, " (null: no converged reference)", 1058)
        p.raise_if_any()


#: ``tracker.mode`` values (W&B's run modes).
TRACKER_MODES = ("offline", "online", "shared", "disabled")


@dataclass
class TrackerConfig:
    """Where each finished grid cell's settings, metrics and images are also logged (conf/tracker/):
    ``none`` (nothing), ``mlflow`` (a local MLflow file store), ``tensorboard`` (event files),
    ``wandb`` (Weights & Biases, offline unless ``mode`` says otherwise). One run per cell, grouped
    by ``experiment``; the cell's own files stay the record (snell_bench/experiment/tracking/).
    Not a result setting."""

    name: str = "none"
    #: The name the runs are grouped under (the MLflow experiment, the W&B group).
    experiment: str = "${experiment_name}"
    #: Also log image.png, reference.png, mask.png and panorama.png (where a cell has them).
    log_images: bool = True
    #: ``mlflow``: the tracking URI (``file:PATH`` or a plain path: a local file store; or a
    #: tracking server's ``http(s)://`` address).
    uri: Optional[str] = None
    #: ``tensorboard``: the log folder (a run folder per cell under it); ``wandb``: the folder
    #: W&B writes its ``wandb/`` folder into.
    dir: Optional[str] = None
    #: ``wandb``: the project and the entity (``null``: the account's default entity).
    project: Optional[str] = None
    entity: Optional[str] = None
    #: ``wandb``: ``offline`` (files only, nothing sent; ``wandb sync`` uploads them later),
    #: ``online``, ``shared`` or ``disabled``.
    mode: Optional[str] = None
    #: The Python modules the back-end imports, checked before any work.
    requires: list = field(default_factory=list)
    #: What logs: a ``_target_`` node (a :class:`~snell_bench.experiment.tracking.Tracker`;
    #: ``null``: no tracking).
    backend: Any = None

    def __post_init__(self) -> None:
        p = Problems("tracker")
        # a module that is not installed stops the run here, before any cell is computed (a
        # tracker that fails later only warns: the cells' results are kept either way)
        missing = [str(m) for m in self.requires if importlib.util.find_spec(str(m)) is None]
        if missing:
            p.append(
                f"tracker={self.name} needs {', '.join(missing)}: pip install 'snell_bench[track]' or set tracker=none"
            )
        if self.mode is not None and self.mode not in TRACKER_MODES:
            p.append(
                f"tracker.mode={self.mode!r}: must be one of {', '.join(TRACKER_MODES)}; e.g. tracker.mode=offline"
            )
        if self.backend is not None and not str(self.experiment).strip():
            p.append(
                f"tracker.experiment={self.experiment!r}: the runs of tracker={self.name} are grouped under this name: "
                "it cannot be empty; e.g. tracker.experiment=my_run (default: experiment_name)"
            )
        p.nonempty_or_null("dir", self.dir, "the log folder, or null for the tracker's default")
        p.nonempty_or_null("uri", self.uri, "a folder, a file: or http(s):// URI, or null")
        p.raise_if_any()


@dataclass
class PlanConfig:
    """``job=plan``: what a grid will do on this machine, before doing it."""

    #: A ``benchmarks/bench_gpu.py --json`` file whose measured times and GPU memory the plan uses
    #: (the pipeline baselines keep the documented figures); ``null``: the documented basis (docs/gpu.md) (the
    #: paper's A100 time scaled), labelled as such.
    bench: Optional[str] = None


@dataclass
class ExportConfig:
    """``job=export``: the benchmark kit of an experiment's grid (``<dir>/<experiment_name>/``): per
    (scene, variation, object) group the inputs a method needs and the truth it is scored against,
    a manifest (Parquet and JSON Lines) and a dataset card (snell_bench/kit/)."""

    #: Where kits are written: ``<dir>/<experiment_name>/``.
    dir: str = "kits"
    #: Also write each group's warps (π^R, π⁻¹, π^-R, π, their masks and the Fresnel reflectance),
    #: for methods that want Snell's law for free (about 60 bytes a pixel).
    warps: bool = False
    #: Export every group again (else a group exported with the same settings, its files unchanged,
    #: is kept; one exported with other settings is exported again).
    recompute: bool = False

    def __post_init__(self) -> None:
        p = Problems("export")
        if not isinstance(self.dir, str) or not self.dir.strip():
            p.append(f"export.dir={self.dir!r}: must be a folder; e.g. export.dir=kits")
        p.raise_if_any()


@dataclass
class Config:
    #: Which job ``python -m snell_bench`` runs.
    job: Job = Job.preview
    seed: int = 0
    scene: SceneConfig = field(default_factory=SceneConfig)
    object: ObjectConfig = field(default_factory=ObjectConfig)
    warps: WarpConfig = field(default_factory=WarpConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    models: ModelsConfig = field(default_factory=ModelsConfig)
    sampler: SamplerSettings = field(default_factory=SamplerSettings)
    method: MethodConfig = field(default_factory=MethodConfig)
    metrics: MetricsConfig = field(default_factory=MetricsConfig)
    baselines: BaselinesConfig = field(default_factory=BaselinesConfig)
    depth: DepthConfig = field(default_factory=DepthConfig)
    segment: SegmentConfig = field(default_factory=SegmentConfig)
    reference: ReferenceConfig = field(default_factory=ReferenceConfig)
    relight: RelightConfig = field(default_factory=RelightConfig)
    grid: GridConfig = field(default_factory=GridConfig)
    tradeoff: TradeoffConfig = field(default_factory=TradeoffConfig)
    plan: PlanConfig = field(default_factory=PlanConfig)
    #: ``job=export``: the benchmark kit.
    export: ExportConfig = field(default_factory=ExportConfig)
    #: Where each finished cell is also logged (conf/tracker/: none, mlflow, tensorboard, wandb).
    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    #: The recipe (conf/recipe/) the switches come from: ``paper`` (what the paper's text says) or
    #: ``authors`` (what the authors' released code does); set by the recipe file, recorded with
    #: every cell.
    recipe: str = "paper"
    #: The experiment's name (its folder under runs/ and reports/).
    experiment_name: str = "default"
    runs_dir: str = "runs"
    reports_dir: str = "reports"
    #: Where the job writes; defaults to Hydra's run directory.
    output_dir: str = MISSING
    #: The overrides this config was composed from (set by ``python -m snell_bench`` and by
    #: :func:`compose`): a sweep composes each of its cells from them and the cell's own choices.
    overrides: list = field(default_factory=list)


#: The nodes whose dataclass checks its own ranges (``sampler`` is checked with the method's
#: switches applied, the root's ``seed`` by :func:`~snell_bench.config.checks.check_config`).
CHECKED_NODES = (
    "scene",
    "object",
    "warps",
    "model",
    "models",
    "method",
    "metrics",
    "baselines",
    "reference",
    "relight",
    "segment",
    "grid",
    "tradeoff",
    "tracker",
    "export",
)
