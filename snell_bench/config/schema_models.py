"""The schema of the models and the method (``model``, ``models``, ``method``, ``depth``, ``segment``, ``relight``): what generates, estimates and relights.

Part of :mod:`snell_bench.config.schema` (its conventions hold here).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Optional

from snell_bench.config.choices import (
    InpaintMask,
    PanoPrior,
    PromptKind,
)
from snell_bench.config.errors import Problems

__all__ = [
    "ModelConfig",
    "ModelsConfig",
    "MethodCostConfig",
    "MethodConfig",
    "DepthConfig",
    "SegmentConfig",
    "RelightConfig",
]


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
    #: What relights (a ``_target_`` node, e.g. ``relight=traced``); ``null``: the model's
    #: relighter (``model.relighter``).
    relighter: Any = None
    #: ``job=relight`` (``+experiment=relighting``): samples per pixel of the path-traced truth.
    truth_spp: int = 512

    def __post_init__(self) -> None:
        p = Problems("relight")
        p.int_at_least("candidates", self.candidates, 1, "", 3)
        # two halves of at least 1 sample each; at most MAX_SPP (config/errors.py: one traced frame per sample)
        p.spp("truth_spp", self.truth_spp, 512, lo=2)
        if self.steps is not None:
            p.int_at_least("steps", self.steps, 1, " (null: the pipeline's default)", 28)
        p.finite("guidance", self.guidance, lo=0.0, optional=True, fix="null: the pipeline's default")
        p.finite("lora_scale", self.lora_scale, fix="the LoRA's weight, e.g. relight.lora_scale=1 (0 turns it off)")
        p.raise_if_any()
