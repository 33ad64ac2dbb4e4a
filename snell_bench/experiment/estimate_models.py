"""``job=plan``'s models: what each model a grid loads is, whether its weights are on this machine
(looked up with the models' own resolvers in local folders and the Hugging Face cache, never
downloading) and, where not, the config key to set; and which cells need it (:func:`grid_models`).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from omegaconf import DictConfig

from snell_bench.experiment.estimate_cells import CellState, GridParts
from snell_bench.methods import method_of
from snell_bench.methods.cost import (
    Basis,
    ModelNeed,
    device_of,
    diffusers_folder,
    documented,
    example,
    find_weights,
    lookup,
)
from snell_bench.pipeline.cell import node_key

__all__ = [
    "FLUX_FILL",
    "FLUX_GENERATOR",
    "KONTEXT",
    "NO_WEIGHTS",
    "OTHER_GB",
    "REAL_BUILDERS",
    "describe_model",
    "grid_models",
    "metric_models",
]

#: GB of other models' weights (docs/gpu.md), by ``depth.name`` / ``segment.name``: MoGe-2 and SAM 3.
OTHER_GB = documented().other_gb

#: ``_target_`` of the builders that need no weights: CPU stand-ins, tiny random models, a mask file.
NO_WEIGHTS = {
    "snell_bench.models.analytic.AnalyticGenerator.from_scene": "analytic (CPU stand-in)",
    "snell_bench.models.mixture.MixtureGenerator.from_scene": "mixture (CPU stand-in)",
    "snell_bench.models.tiny_flux.TinyFluxGenerator": "tiny FLUX (random weights, CPU)",
    "snell_bench.models.tiny_flux.build_tiny_flux_pipeline": "tiny FLUX pipeline (random weights, CPU)",
    "snell_bench.relight.kontext.KontextRelighter.tiny": "tiny FLUX Kontext (random weights, CPU)",
    "snell_bench.relight.shadow.ShadowRelighter": "traced soft shadow (CPU stand-in)",
    "snell_bench.models.depth.tiny_depth_pro": "tiny Depth Pro (random weights, CPU)",
    "snell_bench.models.depth.tiny_depth_anything": "tiny Depth Anything (random weights, CPU)",
    "snell_bench.models.segment.TinySam3Segmenter": "tiny SAM 3 (random weights, CPU)",
    "snell_bench.models.segment.MaskFileSegmenter": "a mask file (segment.mask)",
}
FLUX_GENERATOR = "snell_bench.models.flux.FluxGenerator.from_pretrained"
FLUX_FILL = "snell_bench.models.external.load_pipeline"
KONTEXT = "snell_bench.relight.kontext.KontextRelighter.from_pretrained"
#: ``_target_`` of the builders that read real weights, each looked up by :func:`describe_model`.
REAL_BUILDERS = (
    FLUX_GENERATOR,
    FLUX_FILL,
    KONTEXT,
    "snell_bench.models.depth.MoGe2Depth.from_pretrained",
    "snell_bench.models.depth.TransformersDepth.from_pretrained",
    "snell_bench.models.segment.Sam3Segmenter",
)

#: The FLUX.1 models by pool kind: what they are, the config key of their weights, their entry in
#: :attr:`Basis.memory_gb`.
_FLUX = {
    "generator": ("FLUX.1-dev", "model.path", "flux_dev"),
    "fill": ("FLUX.1-Fill-dev", "model.fill.model_id", "fill"),
    "relighter": ("FLUX.1-Kontext-dev", "model.relighter.model_id", "kontext"),
}


def _transformers_folder(source: str) -> str:
    """A transformers model's folder (with ``config.json``) from a folder or the Hugging Face cache."""
    from snell_bench.models.errors import WeightsNotFoundError

    local = Path(source).expanduser()
    if local.is_dir():
        if (local / "config.json").is_file():
            return str(local)
        raise WeightsNotFoundError(f"the folder {source!r} has no config.json")
    from huggingface_hub import snapshot_download

    try:
        folder = snapshot_download(repo_id=source, local_files_only=True)
    except Exception as err:  # noqa: BLE001 - LocalEntryNotFoundError, HFValidationError, ...
        raise WeightsNotFoundError(f"{source!r} is not a folder and not in the Hugging Face cache") from err
    if not (Path(folder) / "config.json").is_file():
        raise WeightsNotFoundError(f"the cached snapshot {folder!r} has no config.json")
    return folder


def _builder(kind: str, node: Any, name: str) -> ModelNeed | None:
    """The :class:`ModelNeed` of a builder that needs no weights, or of one this plan does not know."""
    target = str(node.get("_target_", "")) if isinstance(node, DictConfig) else ""
    if target in NO_WEIGHTS:
        return ModelNeed(kind, NO_WEIGHTS[target], weights="none", where="built in code, no weights")
    if target in REAL_BUILDERS:
        return None
    return ModelNeed(kind, name, source=target, weights="unchecked", where=f"{target}: not known to job=plan")


def _flux_model(kind: str, c: DictConfig, basis: Basis) -> list[ModelNeed]:
    """FLUX.1-dev (``generator``), FLUX.1-Fill-dev (``fill``) or FLUX.1-Kontext-dev (``relighter``,
    and its LoRA as a second entry), or the model's own builder of that kind."""
    generator = kind == "generator"
    node = c.model.generator if generator else c.model.fill if kind == "fill" else c.model.relighter
    known = _builder(kind, node, c.model.name if generator else f"{c.model.name} {kind}")
    if known is not None:
        return [known]
    name, key, gb = _FLUX[kind]
    source = str(c.model.path if generator else node.model_id)
    device, gpu = device_of(c.model.device if generator else node.get("device"), True)
    need = ModelNeed(kind, name, source, key=key, device=device, needs_gpu=gpu)
    need.memory_gb, need.family = basis.memory_gb[gb], "flux"
    out = [find_weights(need, bool(c.model.get("random_init")), lambda: diffusers_folder(source))]
    lora = node.get("lora") if kind == "relighter" else None
    if lora:
        from snell_bench.relight.kontext import resolve_lora

        state, where = lookup(lambda: resolve_lora(str(lora))[0])
        fix = f"set {example('relight.lora', str(lora))} (a .safetensors file or a folder), or relight.lora=null"
        out.append(ModelNeed("lora", "relighting LoRA", str(lora), state, where, "relight.lora", fix, device, gpu))
    return out


def _input_model(kind: str, c: DictConfig) -> list[ModelNeed]:
    """The depth estimator (``depth``) or the segmenter (``segmenter``) of a group's inputs."""
    group, node = (c.depth, c.depth.estimator) if kind == "depth" else (c.segment, c.segment.segmenter)
    known = _builder(kind, node, group.name)
    if known is not None:
        return [known]
    device, gpu = device_of(group.device, False)
    source, name = str(group.path), group.name
    find: Callable[[str], str] = _transformers_folder
    if name == "moge2":  # MoGe-2's checkpoint file (model.pt), not a transformers folder
        from snell_bench.models.moge import moge_checkpoint

        find = moge_checkpoint
    shown = "SAM 3" if name == "sam3" else name
    key = "depth.path" if kind == "depth" else "segment.path"
    need = ModelNeed(kind, shown, source, key=key, device=device, needs_gpu=gpu, memory_gb=OTHER_GB.get(name))
    return [find_weights(need, False, lambda: find(source))]


def describe_model(kind: str, key: str, c: DictConfig, basis: Basis) -> list[ModelNeed]:
    """What model ``(kind, key)`` of the pool is and whether its weights are here (a config ``c``
    that holds it); a relighter's LoRA comes as a second entry."""
    if kind in _FLUX:
        return _flux_model(kind, c, basis)
    if kind == "pipeline":
        described = method_of(c).describe(kind, key, c, basis)
        if described is not None:
            return described
    if kind in ("depth", "segmenter"):
        return _input_model(kind, c)
    return [ModelNeed(kind, key[:40], weights="unchecked", where="not known to job=plan")]


def metric_models(metrics: DictConfig) -> list[ModelNeed]:
    """The metric backbones every cell is scored with (:func:`snell_bench.metrics.load_scorers`,
    on the CPU): LPIPS's VGG16, CLIP ViT-B/16, ImageReward's interpreter; a missing one is
    reported as a missing metric, never faked."""
    from snell_bench.metrics.alignment import (
        CLIPScore,
        ImageRewardScorer,
        default_clip_checkpoint,
        resolve_clip_checkpoint,
    )
    from snell_bench.metrics.fidelity import _BACKBONE_FILES, MaskedLPIPS

    tv_name, file_name = _BACKBONE_FILES["vgg"]
    lpips, clip = metrics.get("lpips_weights"), metrics.get("clip_weights")
    python = metrics.get("image_reward_python")
    rows: list[tuple[str, str, Any, str, str, Callable[[], Any]]] = [
        (
            "lpips",
            "LPIPS (VGG16)",
            lpips,
            MaskedLPIPS.CONFIG_KEY,
            f"/data/{file_name}",
            lambda: MaskedLPIPS._resolve_weights(lpips, file_name, tv_name, False),
        ),
        (
            "clip",
            "CLIP ViT-B/16",
            clip,
            CLIPScore.CONFIG_KEY,
            "/data/open_clip_model.safetensors",
            lambda: resolve_clip_checkpoint(clip) if clip else default_clip_checkpoint(),
        ),
        (
            "image_reward",
            "ImageReward",
            python,
            ImageRewardScorer.CONFIG_KEY,
            "/env/bin/python",
            lambda: ImageRewardScorer(python).python,
        ),
    ]
    out = []
    for kind, name, source, key, shown, find in rows:
        state, where = lookup(find)
        fix = f"set {key}={shown} (else the metric is reported as missing)" if state == "missing" else ""
        out.append(ModelNeed(kind, name, str(source or ""), state, where, key, fix, "cpu", False, None))
    return out


def _cell_models(
    parts: GridParts, scene: str, method: str, described: dict[tuple[str, str], list[ModelNeed]], basis: Basis
) -> list[ModelNeed]:
    """The models a cell of ``scene`` and ``method`` needs, each described once in ``described``."""
    found: list[ModelNeed] = []
    for kind, key in parts.models(scene, method):
        if (kind, key) not in described:
            src = parts.method(method) if kind in ("fill", "relighter", "pipeline") else parts.scene(scene)
            described[(kind, key)] = describe_model(kind, key, src, basis)
        found += [m for m in described[(kind, key)] if all(m is not f for f in found)]
    c = parts.method(method)
    if c.model.from_scene and method_of(c).uses_generator(c):  # the group's own generator (not the pool's): listed too
        own = ("generator", "from_scene " + node_key(c.model))
        if own not in described:
            described[own] = describe_model("generator", own[1], c, basis)
        found += described[own]
    return found


def grid_models(
    cfg: DictConfig, parts: GridParts, cells: list[CellState], basis: Basis
) -> tuple[dict[tuple[str, str], list[ModelNeed]], list[ModelNeed]]:
    """The models each ``(scene, method)`` of ``cfg.grid`` needs, and every model of the grid (the
    metric backbones last) with the methods and the cells (and cells left) that need it."""
    g = cfg.grid
    described: dict[tuple[str, str], list[ModelNeed]] = {}
    per_pair = {
        (scene, method): _cell_models(parts, scene, method, described, basis)
        for scene in map(str, g.scenes)
        for method in map(str, g.methods)
    }
    for c in cells:
        for m in per_pair[(c.scene, c.method)]:
            m.cells += 1
            m.cells_left += int(not c.done)
            if c.method not in m.methods:
                m.methods.append(c.method)
    metrics = metric_models(cfg.metrics)
    for m in metrics:
        m.cells, m.cells_left, m.methods = len(cells), sum(not c.done for c in cells), [str(x) for x in g.methods]
    return per_pair, [m for ms in described.values() for m in ms] + metrics
