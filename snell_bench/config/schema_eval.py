"""The schema of the evaluation (``metrics``, ``baselines``, ``reference``): what an image is scored against, and how.

Part of :mod:`snell_bench.config.schema` (its conventions hold here).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

from snell_bench.config.choices import (
    PromptKind,
    Protocol,
    RefMask,
    RefRenderer,
    RefSampler,
)
from snell_bench.config.errors import Problems

__all__ = ["MetricsConfig", "BaselinesConfig", "ReferenceConfig"]


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
        # every sample count at most MAX_SPP (config/errors.py: what the renderers take)
        p.spp("cycles_spp", self.cycles_spp, 1024)
        p.finite("ior", self.ior, lo=1.0, hi=4.0, optional=True, fix="e.g. reference.ior=1.5 (null: the object's)")
        p.spp("spp", self.spp, 242)
        if self.unobserved_spp is not None:
            p.spp("unobserved_spp", self.unobserved_spp, 25, why="null: spp; ")
        p.int_at_least("crop_margin_px", self.crop_margin_px, 0, "", 4)
        p.spp("true_spp", self.true_spp, 4)
        if self.true_max_bounces is not None:
            p.int_at_least("true_max_bounces", self.true_max_bounces, 1, " (null: warps.max_bounces)", 16)
        # a pixel counts when its unobserved share is below the threshold: 0 would leave no pixel to score
        p.finite("unobserved_threshold", self.unobserved_threshold, positive=True, hi=1.0, fix="e.g. 0.05")
        p.raise_if_any()
