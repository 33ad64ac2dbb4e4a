"""The recipes: every switch where the paper's text, the authors' released code and snell_bench's own
options differ, with the value each recipe sets.

``conf/recipe/paper.yaml`` (the default) and ``conf/recipe/authors.yaml`` set exactly these keys
(a test holds them to this table), and the documentation's "Reproducing the paper" (``docs/paper.md``)
prints it with the effect of each switch measured on CPU (``benchmarks/bench_recipes.py``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

__all__ = ["BEFORE_SWITCHES", "RECIPES", "SWITCHES", "Switch", "recipe_values"]

#: The recipe names (``conf/recipe/<name>.yaml``).
RECIPES = ("paper", "authors")


@dataclass(frozen=True)
class Switch:
    """One config key on which the paper, the authors' code and snell_bench may differ.

    Attributes:
        key: the dotted config key (``sampler.tt_mode``).
        paper: the value the paper's text implies.
        authors: the value the authors' released code uses.
        own: snell_bench's own option where it goes beyond both (``None``: none).
        what: one line on what the switch changes.
    """

    key: str
    paper: Any
    authors: Any
    own: Any
    what: str


SWITCHES: tuple[Switch, ...] = (
    Switch(
        "sampler.schedule", "flux", "linear", None, "noise levels: the resolution-shifted FLUX schedule, or unshifted"
    ),
    Switch("sampler.sde", False, True, None, "step: deterministic Euler, or Euler-Maruyama (z + dt v + abs(dt) n)"),
    Switch("sampler.encode", "mean", "sample", None, "VAE encode of the synchronised images: posterior mean or a draw"),
    Switch("sampler.quantize", False, True, None, "8-bit round trip of the decoded and synchronised estimates"),
    Switch("sampler.sync_last_step", True, False, None, "synchronise the last step too"),
    Switch(
        "sampler.tt_mode",
        "guided",
        "guided",
        "repaint",
        "time travel: back from t + l with the estimate at t (guided), or re-predicted at every level (repaint)",
    ),
    Switch(
        "sampler.tt_window_floor",
        False,
        True,
        None,
        "time-travel window: 0.2 T <= i < 0.8 T, or both bounds rounded down (the same at T = 20)",
    ),
    Switch(
        "sampler.tt_renoise", "exact", "euler_maruyama", None, "time travel's renoising: exact kernel or Euler-Maruyama"
    ),
    Switch(
        "sampler.dpa_domain",
        "image",
        "image",
        "bands",
        "where DPA blends: whole images in [-1, 1], or each Laplacian band (low-pass in [-1, 1])",
    ),
    Switch(
        "sampler.lpw_pano",
        True,
        False,
        None,
        "Laplacian pyramid warping also into the panorama, or single-level remaps there",
    ),
    Switch(
        "sampler.pano_to_main",
        "frame",
        "frame",
        "object",
        "pixels of the main view that blend the panorama: the whole frame, or the object only",
    ),
    Switch(
        "sampler.latent_dtype",
        "float32",
        "float16",
        None,
        "latents between steps: float32, or rounded to float16 (the authors' float16 pipeline)",
    ),
    Switch("model.dtype", None, "float16", None, "the generator's weights: the device's default (CUDA: bf16), or fp16"),
    Switch("model.vae_tiling", True, False, None, "the VAE decodes and encodes in overlapping tiles, or whole"),
    Switch("depth.edge_rtol", None, 0.1, None, "MoGe-2 depth edges: kept, or cut where the 3 x 3 spread > 0.1 x depth"),
    Switch(
        "segment.instance", "union", "first", None, "SAM 3 instances above the threshold: their union, or the first"
    ),
    Switch(
        "object.anchor",
        "plane",
        "centre_ray",
        None,
        "where the object stands: a plane fitted to the surface, or the ray through its box centre (+5 mm up)",
    ),
    Switch(
        "warps.back_faces",
        False,
        True,
        None,
        "π^R: a refracted ray ending on the back of the depth mesh is unobserved, or takes the pixel there",
    ),
    Switch("warps.normals", "interpolated", "face", None, "the object's shading normals: interpolated, or flat faces"),
    Switch(
        "warps.recipe_max_bounces", None, 12, None, "interactions per refracted path: the preset's max_bounces, or 12"
    ),
    Switch(
        "warps.half_pixel_shift",
        False,
        True,
        None,
        "perspective maps (π^R, π) shifted +0.5 px: pixel-edge coordinates read by grid_sample(align_corners=True)",
    ),
    Switch(
        "warps.reflection_parallax",
        True,
        False,
        None,
        "π^-R: the mirror ray's end seen from the panorama centre (occlusion-tested), or its direction alone",
    ),
    Switch(
        "warps.pano_center",
        "bbox",
        "centroid",
        None,
        "panorama centre: the object's box centre, or its surface centroid",
    ),
    Switch("warps.pano_axes", "level", "camera", None, "panorama axes: gravity-level, or the camera's own"),
    Switch("reference.reflection", False, False, True, "the reference includes the first-surface reflection"),
    Switch(
        "reference.renderer",
        "mitsuba",
        "cycles",
        None,
        "reference renderer: Mitsuba, unlit (I⁻ emitted), or Cycles lit as render_gt (light, world, exposure, AgX, JPEG)",
    ),
    Switch("reference.ior", None, 1.5, None, "the reference glass's IOR: the object's, or 1.5 whatever the object"),
    Switch(
        "reference.mask",
        "unobserved",
        "authors",
        None,
        "metric mask: light from observed surfaces, or one refracted ray reaching the background (render_gt)",
    ),
    Switch(
        "metrics.protocol",
        "paper",
        "authors",
        None,
        "evaluation: the paper's text, or eval/masked_metrics.py (adds lpips_box)",
    ),
    Switch(
        "metrics.files",
        "png",
        "jpeg",
        None,
        "files scored: lossless, or the JPEGs eval/eval.py reads (q75, q95, mask q75)",
    ),
    Switch(
        "baselines.object_phrase",
        None,
        "a solid transparent glass {object}",
        None,
        "the object phrase of the baselines' prompts: the scene's p_obj, or the authors' (eval/compare*.py)",
    ),
    Switch("baselines.flux_steps", None, 28, None, "FLUX text-to-image steps: sampler.steps, or FluxPipeline's 28"),
    Switch("baselines.fill_steps", None, 30, None, "FLUX Fill steps: the pipeline's 50, or 30"),
    Switch("baselines.fill_guidance", None, 30.0, None, "FLUX Fill guidance: the pipeline's default (30), or 30"),
    Switch(
        "baselines.qwen_model_id", "Qwen/Qwen-Image", "Qwen/Qwen-Image-2512", None, "the Qwen-Image baseline's model"
    ),
    Switch("baselines.qwen_cfg", True, False, None, 'Qwen-Image\'s true CFG (negative prompt " "), or none'),
    Switch("relight.lora", None, "kontext-community/relighting-kontext-dev-lora-v3", None, "relighting LoRA"),
)
"""Every recipe switch, in the order of the table in ``docs/paper.md``."""

#: Keys a recipe sets beyond :data:`SWITCHES` (the authors' relighting candidates; the paper's
#: count, 20, is the ``paper`` preset's, a cost setting).
EXTRA = {"authors": {"relight.candidates": 3}, "paper": {}}


def recipe_values(name: str) -> dict[str, Any]:
    """The dotted keys and values recipe ``name`` sets.

    Raises:
        ValueError: for an unknown recipe, naming the choices.
    """
    if name not in RECIPES:
        raise ValueError(f"unknown recipe {name!r}: use recipe=paper or recipe=authors")
    values = {s.key: getattr(s, name) for s in SWITCHES}
    values.update(EXTRA[name])
    return values


#: What the code did before a recipe switch existed, for cells recorded before it: a key absent from
#: a finished cell's record counts as unchanged only if the current value is this one (keys not
#: listed: the schema default). The per-band blend with its low-pass level in [0, 1] and the
#: pyramid-warp switch that also turned band blending off are no longer a setting, so no value
#: matches them.
BEFORE_SWITCHES: dict[str, Any] = {
    "recipe": None,
    "sampler.tt_mode": "repaint",
    "sampler.pano_to_main": "object",
    "sampler.dpa_domain": "<per band, low-pass in [0, 1]>",
    "reference.reflection": True,
    "metrics.score_file": False,
}
