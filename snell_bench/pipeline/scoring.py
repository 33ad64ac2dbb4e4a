"""Stage 8: masked metrics of a method's image against the reference, and the method's whole run
(stages 6-8, :func:`run_method`)."""

from __future__ import annotations

from pathlib import Path

import torch
from omegaconf import DictConfig, OmegaConf

from snell_bench.config import Source
from snell_bench.metrics import load_scorers, score_cell
from snell_bench.pipeline.cell import CellInputs, CellResult, Degenerate, node_key, plain, prompt_of
from snell_bench.pipeline.degenerate import warps_problem
from snell_bench.pipeline.inputs import trace_warps
from snell_bench.pipeline.methods import relight_image, sample_method
from snell_bench.pipeline.pool import ModelPool
from snell_bench.utils.io import save_png, saved_pixels
from snell_bench.utils.tensors import bchw_to_hwc
from snell_bench.utils.timing import Timer

__all__ = ["clip_prompt", "scorers_of", "score", "run_method", "sample_stage", "finish_method"]


def scorers_of(metrics_cfg: DictConfig, pool: ModelPool):
    """The metric backbones of a ``metrics`` node (LPIPS, CLIP, ImageReward; each missing with its
    reason where it cannot load) from the pool, pinned: every cell of a sweep scores with them."""
    return pool.get("scorers", node_key(metrics_cfg), lambda: load_scorers(metrics_cfg), label="metrics", pin=True)[0]


def clip_prompt(cfg: DictConfig) -> str:
    """The text CLIP and ImageReward score against: the scene's entry of the ``metrics.clip_prompts``
    file (``{object}``: the object's noun) where it lists the scene, else ``metrics.clip_text``.

    Raises:
        ValueError: the file cannot be read, is not a mapping of scene names to texts (naming
            ``metrics.clip_prompts``).
    """
    path = cfg.metrics.get("clip_prompts")
    if path:
        try:
            table = OmegaConf.to_container(OmegaConf.load(Path(str(path)).expanduser()))
        except Exception as e:  # noqa: BLE001 - any unreadable file: say which and why
            raise ValueError(
                f"metrics.clip_prompts={str(path)!r} cannot be read ({e}); give a YAML or JSON file"
            ) from e
        if not isinstance(table, dict) or not all(isinstance(v, str) for v in table.values()):
            raise ValueError(f"metrics.clip_prompts={str(path)!r} is not a mapping {{scene name: text}}")
        text = table.get(cfg.scene.name)
        if text is not None:
            return text.replace("{object}", cfg.object.noun)
    return prompt_of(cfg, cfg.metrics.clip_text, "metrics.clip_text")


def score(
    cfg: DictConfig, inputs: CellInputs, image: torch.Tensor, scorers, *, image_path=None, reference=None
) -> dict:
    """Stage 8: masked metrics of ``image`` against the reference (``reference``: another
    ReferenceRender to score against, e.g. a converged one) and PSNR against the true render, under
    ``metrics.protocol``: ``{"metrics": {name: float | None}, "missing": {name: reason}, "protocol":
    ...}`` with ``lpips_box`` under ``authors`` only. With ``metrics.score_file`` (the default) the
    image is scored as its 8-bit PNG holds it (:func:`~snell_bench.utils.io.saved_pixels`), so
    re-scoring the saved ``image.png`` (``method=images``, :func:`snell_bench.kit.score_image`)
    gives the same numbers; under ``authors`` the reference too is scored as its 8-bit PNG;
    ``metrics.files=jpeg`` scores the JPEG files the authors' evaluation reads instead; CLIP and
    ImageReward see :func:`clip_prompt`; users' metrics (``metrics.extra``) follow the built-in ones.
    A procedural scene without its true render (``reference.true_render=false``) records
    ``psnr_true`` as missing with that reason; a photo or generated scene has no truth and no
    ``psnr_true``."""
    ref = inputs.reference if reference is None else reference
    pixels = bchw_to_hwc(image)
    if cfg.metrics.get("score_file", True):  # as image.png holds it: every method and any saved image alike
        pixels = saved_pixels(pixels)
    scored = score_cell(
        pixels,
        None if ref is None else ref.image,
        None if ref is None else ref.mask,
        clip_prompt(cfg),
        scorers,
        reference_reason=inputs.reference_reason,
        true_render=inputs.true_render if reference is None else None,
        object_mask=inputs.warps.object_mask,
        generated_path=image_path,
        protocol=str(cfg.metrics.protocol),
        files=str(cfg.metrics.get("files", "png")),
        lpips_box_range=str(cfg.metrics.get("lpips_box_range", "signed")),
        reference_is_jpeg=getattr(ref, "file_format", None) == "jpeg",
        extra=tuple(str(m) for m in (cfg.metrics.get("extra") or ())),
    )
    if reference is None and inputs.true_render is None and cfg.scene.source is Source.procedural:
        scored["metrics"]["psnr_true"] = None  # a procedural scene has a truth: say why it is not scored
        scored["missing"]["psnr_true"] = "no true render (reference.true_render=false)"
    return scored


def sample_stage(cfg: DictConfig, inputs: CellInputs) -> CellResult:
    """Stages 6-7 of one method (``cfg`` with :func:`~snell_bench.pipeline.apply_method` applied),
    before relighting. A method whose ``warps`` settings differ from those the inputs were traced
    with gets its own warps (timed as ``warps``)."""
    t = Timer()
    warps = inputs.warps
    if plain(cfg.warps) != inputs.warps_config:
        with t("warps"):
            warps = trace_warps(inputs.scene, inputs.obj, cfg.warps)
        if (problem := warps_problem(warps, cfg.warps.max_bounces)) is not None:
            raise Degenerate(problem)
    result = sample_method(cfg, inputs, warps, t)
    _check_result(cfg, result, warps)
    if result.warps is None:  # a user's method need not hand its warps back
        result.warps = warps
    result.timings = {**t.seconds, **result.timings}
    return result


def _check_result(cfg: DictConfig, result, warps) -> None:
    """A method's result is a :class:`~snell_bench.pipeline.CellResult` whose image is ``(1, 3, H,
    W)`` float of the scene's camera (a user's method is told what it returned instead)."""
    where = f"method={cfg.method.name} (kind {cfg.method.kind})"
    image = getattr(result, "image", None)
    if not isinstance(image, torch.Tensor):
        raise TypeError(f"{where} returned {type(result).__name__}, not a CellResult with an image tensor")
    shape = (1, 3, warps.camera.height, warps.camera.width)
    if tuple(image.shape) != shape or not image.is_floating_point():
        raise ValueError(
            f"{where} returned an image of shape {tuple(image.shape)} and dtype {image.dtype}; expected {shape} "
            "float (sRGB in [0, 1])"
        )


def finish_method(
    cfg: DictConfig, inputs: CellInputs, result: CellResult, *, scorers=None, image_path=None
) -> CellResult:
    """Stages 7b-8 of a method after :func:`sample_stage`: relighting (``method.relight``), the
    image saved to ``image_path`` (and the un-relit one beside it), and the scores (with
    ``scorers``)."""
    t = Timer()
    if cfg.method.relight:
        result = relight_image(cfg, inputs, result, t)
    if scorers is not None:
        if image_path is not None:
            save_png(image_path, bchw_to_hwc(result.image))
            if result.unrelit is not None:
                p = Path(image_path)
                save_png(p.with_name(f"{p.stem}_unrelit{p.suffix}"), bchw_to_hwc(result.unrelit))
        with t("metrics"):
            result.scores = score(cfg, inputs, result.image, scorers, image_path=image_path)
    result.timings = {**result.timings, **t.seconds}
    return result


def run_method(cfg: DictConfig, inputs: CellInputs, *, scorers=None, image_path=None) -> CellResult:
    """Stages 6-8: one method (``cfg`` with :func:`~snell_bench.pipeline.apply_method` applied) on
    shared inputs, with the models of ``inputs.pool``.

    With ``scorers`` (:func:`scorers_of`, :func:`snell_bench.metrics.load_scorers`) the image is
    scored and ``CellResult.scores`` filled; ``image_path`` is the saved image, handed to scorers
    that read files. Raises :class:`~snell_bench.pipeline.Skip` for a method that cannot run here.
    """
    return finish_method(cfg, inputs, sample_stage(cfg, inputs), scorers=scorers, image_path=image_path)
