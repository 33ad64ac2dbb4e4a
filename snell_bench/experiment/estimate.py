"""``job=plan``: what a grid will do on this machine, before doing it.

``python -m snell_bench job=plan +experiment=main model=flux_dev`` prints, and writes nothing:

- the grid's cells and groups (scene x variation x object), which are done and which are left,
  with the runner's own test of "done" (:mod:`snell_bench.experiment.cells`: the record says ``ok``
  or ``skipped``, the files it lists are unchanged, its settings hash equals the cell's now; a
  cell finished with other settings is *changed*);
- every model the cells need (the generator, FLUX Fill, the relighter and its LoRA, the pipeline
  baselines, the depth estimator, the segmenter, the metric backbones), whether its weights are on
  this machine (a folder or the Hugging Face cache, looked up with the models' own resolvers,
  never downloading) and, where not, the config key to set; whether a GPU is needed and present;
- the time and GPU memory per cell and in total, from a ``benchmarks/bench_gpu.py --json`` file
  (``plan.bench``) or else the documented basis (docs/gpu.md), always labelled with where the figures come from;
  whether the models fit together, else the model-major order with offloading.

Convention:
    - Nothing is written: no folder, no file, no log (:mod:`snell_bench.config.preflight` keeps
      Hydra's run folder, its ``.hydra/`` copy and its log file away for ``job=plan``), and no
      weight is downloaded or loaded.
    - Cells are not composed one by one (a Hydra composition costs ~0.1 s, the main grid has
      1800 cells): each scene, object and method is composed once with the run's overrides
      (:class:`GridParts`), and a cell's settings are the union of its parts' (a scene's config
      group touches only the ``scene`` node, an object's only ``object``, a method's only
      ``method``, and its switches only the ``sampler`` / ``warps`` keys it names), the same as
      composing the cell (``tests/experiment/test_job_plan.py`` holds them equal to
      :func:`~snell_bench.experiment.runner.plan_grid`). Objects are composed only when a cell
      has a record to compare with.
    - Times are seconds per cell as ``(low, high)``; memory is in GB (10⁹ bytes) of bfloat16
      weights, the documented unit (``models.memory_gb`` is GiB and is converted). FLUX Fill and
      FLUX Kontext share FLUX.1-dev's text encoders and VAE: loaded together, those count once.
    - A basis is scaled to a cell's settings linearly: the synchronized sampler by its model
      calls weighted by their pixels (:func:`model_calls`), the pipelines by steps x pixels. The
      scaling is an approximation and is printed with every row.
"""

from __future__ import annotations

import json
import math
import os
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from snell_bench.config import ConfigError, OnChange, Source, check_grid_entries, compose
from snell_bench.experiment.cells import Cell, ChangedCell, SettingsChanged, cell_state
from snell_bench.experiment.order import cell_models
from snell_bench.experiment.plan import (
    NOT_RESULT_KEYS,
    check_reproducible,
    flatten,
    object_dir_name,
    object_overrides,
    result_settings,
    settings_hash,
)
from snell_bench.experiment.reports.records import GRID_RECORD
from snell_bench.kit.schema import kit_id
from snell_bench.methods import method_of
from snell_bench.methods.cost import (
    CPU_LABEL,
    README_BASIS,
    README_LABEL,
    Basis,
    Estimate,
    ModelNeed,
    device_of,
    diffusers_folder,
    example,
    find_weights,
    lookup,
    model_calls,
    relight_estimate,
    secs,
    together_gb,
)
from snell_bench.pipeline import apply_method
from snell_bench.pipeline.cell import node_key

__all__ = [
    "Basis",
    "README_BASIS",
    "load_bench",
    "model_calls",
    "group_models",
    "GridParts",
    "CellState",
    "ModelNeed",
    "DeviceInfo",
    "local_device",
    "Estimate",
    "MethodTime",
    "Plan",
    "make_plan",
    "format_plan",
    "run_plan",
]

RECORD = "metrics.json"

# ---------------------------------------------------------------------------- the bases of the estimates
#: GB of other models' weights (docs/gpu.md): MoGe-2 and SAM 3.
OTHER_GB = {"moge2": 1.3, "sam3": 3.4}

_BENCH_KEYS = (
    "device",
    "settings.steps",
    "settings.height",
    "settings.width",
    "settings.pano_height",
    "pair.total_s",
    "pair.model_calls.main",
    "pair.model_calls.pano",
    "pair.peak_memory_gb",
    "t2i.total_s",
    "t2i.steps",
    "t2i.peak_memory_gb",
    "fill.total_s",
    "fill.steps",
    "fill.peak_memory_gb",
    "kontext.total_s",
    "kontext.steps",
    "kontext.candidates",
    "kontext.peak_memory_gb",
    "memory_gb.flux_dev",
    "memory_gb.fill",
    "memory_gb.kontext",
    "memory_gb.shared_text_vae",
)


def load_bench(path: str | os.PathLike) -> Basis:
    """The :class:`Basis` of a ``benchmarks/bench_gpu.py --json`` file (config key ``plan.bench``).

    Raises:
        FileNotFoundError, IsADirectoryError: naming ``plan.bench``, when the file is not there.
        ConfigError: naming ``plan.bench`` and every missing or unusable field at once (a number
            must be finite and positive, a count an integer), or a file that is not JSON.
    """
    from snell_bench.utils.paths import data_path

    file = data_path(str(path), "plan.bench", "bench_gpu.py JSON file")
    fix = "give the file `python benchmarks/bench_gpu.py --json` wrote, or plan.bench=null for the documented basis (docs/gpu.md)"
    try:
        data = json.loads(Path(file).read_text())
    except (OSError, ValueError) as e:
        raise ConfigError([f"plan.bench={str(path)!r} is not a JSON file ({type(e).__name__}: {e}); {fix}"]) from None
    if not isinstance(data, dict):
        raise ConfigError([f"plan.bench={str(path)!r} holds a {type(data).__name__}, not a JSON object; {fix}"])
    problems, values = [], {}
    for key in _BENCH_KEYS:
        node: Any = data
        for part in key.split("."):
            node = node.get(part) if isinstance(node, dict) else None
        if key == "device":
            ok = isinstance(node, str) and bool(node)
        elif key.endswith(("steps", "height", "width", "main", "pano", "candidates")):
            ok = isinstance(node, int) and not isinstance(node, bool) and node >= (0 if key.endswith("pano") else 1)
        else:
            ok = isinstance(node, (int, float)) and not isinstance(node, bool) and math.isfinite(node) and node > 0
        if not ok:
            problems.append(f"{key} {'missing' if node is None else f'{node!r} is not usable'}")
        values[key] = node
    if problems:
        raise ConfigError([f"plan.bench={str(path)!r}: {', '.join(problems)}; {fix}"])
    v = values
    dtype = data.get("dtype", "?")
    random = " with random weights" if data.get("random_weights") else ""
    kontext = v["kontext.total_s"] / v["kontext.candidates"]
    return Basis(
        label=f"measured: benchmarks/bench_gpu.py on {v['device']} ({dtype}{random}), {file}",
        measured=True,
        pair_s=(v["pair.total_s"],) * 2,
        pair_calls=(v["pair.model_calls.main"], v["pair.model_calls.pano"]),
        size=(v["settings.height"], v["settings.width"], v["settings.pano_height"]),
        t2i_s=(v["t2i.total_s"],) * 2,
        t2i_steps=v["t2i.steps"],
        fill_s=(v["fill.total_s"],) * 2,
        fill_steps=v["fill.steps"],
        kontext_s=(kontext, kontext),
        kontext_steps=v["kontext.steps"],
        memory_gb={k: float(v[f"memory_gb.{k}"]) for k in ("flux_dev", "fill", "kontext", "shared_text_vae")},
        peak_gb={k: float(v[f"{k}.peak_memory_gb"]) for k in ("pair", "t2i", "fill", "kontext")},
    )


# ---------------------------------------------------------------------------- the models of a cell
def group_models(c: DictConfig) -> list[tuple[str, str]]:
    """``(kind, key)`` of the pool's models the inputs of a group load (stages 1-2 of
    :func:`snell_bench.pipeline.prepare_inputs`): the generator that makes a generated I⁻ (unless
    cached), the depth estimator of a photo without depth or of a generated I⁻, the segmenter."""
    out = []
    source = Source.of(c.scene.source, "scene.source")
    if source is Source.generated and not c.model.from_scene:
        out.append(("generator", node_key(c.model)))
    if ((source is Source.image and not c.scene.depth) or source is Source.generated) and c.depth.get("estimator"):
        out.append(("depth", node_key(c.depth)))
    if c.segment.get("segmenter"):
        out.append(("segmenter", node_key(c.segment)))
    return out


def _node_settings(c: DictConfig, node: str) -> dict[str, Any]:
    """:func:`~snell_bench.experiment.plan.result_settings` of one top-level node of ``c``,
    resolved against the whole config."""
    values = OmegaConf.to_container(c[node], resolve=True, enum_to_str=True)
    flat = flatten(values, f"{node}.") if isinstance(values, dict) and values else {node: values}
    return {k: v for k, v in flat.items() if not any(k == n or k.startswith(n + ".") for n in NOT_RESULT_KEYS)}


class GridParts:
    """The configs of a grid's scenes, objects and methods, each composed once with the run's
    overrides, and the cells' settings put together from them (see the module's convention).

    Args:
        cfg: the run's config (composed from ``cfg.overrides``).
        compose_fn: composes a list of overrides (:func:`snell_bench.config.compose`).
    """

    def __init__(self, cfg: DictConfig, compose_fn: Callable[[list[str]], DictConfig] = compose) -> None:
        self.cfg = cfg
        self._compose = compose_fn
        self._run = [str(o) for o in cfg.overrides]
        self._cache: dict[tuple, Any] = {}
        self.compositions = 0

    def _get(self, key: tuple, make: Callable[[], Any]) -> Any:
        if key not in self._cache:
            self._cache[key] = make()
        return self._cache[key]

    def _composed(self, overrides: list[str]) -> DictConfig:
        self.compositions += 1
        return self._compose([*self._run, *overrides])

    def scene(self, name: str) -> DictConfig:
        """The run's config with ``scene=name`` (the group inputs' models, the image size)."""
        return self._get(("scene", name), lambda: self._composed([f"scene={name}"]))

    def method(self, name: str) -> DictConfig:
        """The run's config with ``method=name``, its switches applied."""
        return self._get(("method", name), lambda: apply_method(self._composed([f"method={name}"])))

    def object(self, spec: str) -> DictConfig:
        """The run's config with the object of ``spec``."""
        return self._get(("object", spec), lambda: self._composed(object_overrides(spec)))

    def settings(self, scene: str, variation: int, spec: str, method: str) -> dict[str, Any]:
        """``result_settings`` of the cell, from its parts."""

        def rest():
            return {
                k: v for k, v in result_settings(self.cfg).items() if not k.startswith(("scene.", "object.", "method."))
            }

        def scene_part():
            c = self.scene(scene).copy()
            c.scene.variation = int(variation)  # as the override scene.variation=N after scene=NAME
            return _node_settings(c, "scene")

        def method_part():
            c = self.method(method)
            own = [f"sampler.{n}" for n in (c.method.sampler or {})] + [f"warps.{n}" for n in (c.method.warps or {})]
            switched = {
                k: v
                for node in ("sampler", "warps")
                for k, v in _node_settings(c, node).items()
                if any(k == o or k.startswith(o + ".") for o in own)
            }
            return {**_node_settings(c, "method"), **switched}

        return {
            **self._get(("rest",), rest),
            **self._get(("scene-settings", scene, int(variation)), scene_part),
            **self._get(("object-settings", spec), lambda: _node_settings(self.object(spec), "object")),
            **self._get(("method-settings", method), method_part),
        }

    def models(self, scene: str, method: str) -> list[tuple[str, str]]:
        """``(kind, key)`` of the pool's models a cell of ``scene`` and ``method`` needs, as
        :func:`group_models` of its inputs and :func:`~snell_bench.experiment.order.cell_models`."""
        return self._get(
            ("models", scene, method), lambda: group_models(self.scene(scene)) + cell_models(self.method(method))
        )


# ---------------------------------------------------------------------------- the cells
@dataclass(frozen=True)
class CellState:
    """One cell of the grid and what a run would do with it.

    ``state``: ``done`` (``ok``), ``skipped`` (recorded as skipped: done, not run again), ``changed``
    (finished with other settings: ``diff`` names them), ``files`` (a listed file is missing or
    changed, or an input the method read has: computed again), ``failed`` (recorded as failed: computed again), ``new`` (no record),
    ``recompute`` (``grid.recompute=true``)."""

    scene: str
    variation: int
    object: str
    method: str
    folder: Path
    state: str
    reason: str = ""
    diff: dict = field(default_factory=dict)

    @property
    def name(self) -> str:
        return f"{self.scene}-{self.variation}/{object_dir_name(self.object)}/{self.method}"

    @property
    def done(self) -> bool:
        return self.state in ("done", "skipped")


def cell_states(cfg: DictConfig, parts: GridParts) -> list[CellState]:
    """Every cell of ``cfg.grid`` in the runner's order, with its state (:class:`CellState`, by
    :func:`snell_bench.experiment.cells.cell_state`, the runner's own rule); nothing is written."""
    g = cfg.grid
    root = Path(cfg.runs_dir) / str(cfg.experiment_name)
    out = []
    for scene in g.scenes:
        for variation in g.variations:
            for spec in g.objects:
                for method in g.methods:
                    ident = (str(scene), int(variation), str(spec), str(method))
                    folder = root / f"{scene}-{variation}" / object_dir_name(str(spec)) / str(method)
                    out.append(_state(ident, folder, parts, bool(g.recompute)))
    return out


def _state(ident: tuple, folder: Path, parts: GridParts, recompute: bool) -> CellState:
    c = parts.method(ident[3])
    group = kit_id(ident[0], ident[1], object_dir_name(ident[2]))

    def current() -> tuple[dict, str]:
        settings = parts.settings(*ident)
        return settings, settings_hash(settings)

    cell = Cell(name=folder.name, folder=folder, config=None, record={})  # the identity the state reads
    st = cell_state(
        cell,
        current,
        record_name=RECORD,
        schema=GRID_RECORD,
        recompute=recompute,
        stale=lambda cell, record: method_of(c).stale(c, record, folder, group),
    )
    return CellState(*ident, folder, "new" if st.kind == "damaged" else st.kind, st.reason, st.diff)


# ---------------------------------------------------------------------------- devices
@dataclass(frozen=True)
class DeviceInfo:
    """The CUDA device of this machine (``cuda``: one is available; ``memory_gb``: of device 0)."""

    cuda: bool
    name: str = ""
    memory_gb: float | None = None
    count: int = 0


def local_device() -> DeviceInfo:
    """This machine's CUDA device 0 (``torch.cuda``), or none."""
    import torch

    if not torch.cuda.is_available():
        return DeviceInfo(cuda=False)
    props = torch.cuda.get_device_properties(0)
    return DeviceInfo(True, str(props.name), props.total_memory / 1e9, torch.cuda.device_count())


# ---------------------------------------------------------------------------- models and their weights
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


def _moge_file(source: str) -> str:
    from snell_bench.models.moge import _moge_checkpoint

    return _moge_checkpoint(source)


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


def _builder(kind: str, node: Any, name: str) -> ModelNeed | None:
    """The :class:`ModelNeed` of a builder that needs no weights, or of one this plan does not know."""
    target = str(node.get("_target_", "")) if isinstance(node, DictConfig) else ""
    if target in NO_WEIGHTS:
        return ModelNeed(kind, NO_WEIGHTS[target], weights="none", where="built in code, no weights")
    if target in REAL_BUILDERS:
        return None
    return ModelNeed(kind, name, source=target, weights="unchecked", where=f"{target}: not known to job=plan")


def describe_model(kind: str, key: str, c: DictConfig, basis: Basis) -> list[ModelNeed]:
    """What model ``(kind, key)`` of the pool is and whether its weights are here (a config ``c``
    that holds it); a relighter's LoRA comes as a second entry."""
    random = bool(c.model.get("random_init"))
    mem = basis.memory_gb
    if kind == "generator":
        known = _builder(kind, c.model.generator, str(c.model.name))
        if known is not None:
            return [known]
        device, gpu = device_of(c.model.device, True)
        need = ModelNeed(kind, "FLUX.1-dev", str(c.model.path), key="model.path", device=device, needs_gpu=gpu)
        need.memory_gb, need.family = mem["flux_dev"], "flux"
        return [find_weights(need, random, lambda: diffusers_folder(str(c.model.path)))]
    if kind == "fill":
        node = c.model.fill
        known = _builder(kind, node, f"{c.model.name} fill")
        if known is not None:
            return [known]
        device, gpu = device_of(node.get("device"), True)
        source = str(node.model_id)
        need = ModelNeed(kind, "FLUX.1-Fill-dev", source, key="model.fill.model_id", device=device, needs_gpu=gpu)
        need.memory_gb, need.family = mem["fill"], "flux"
        return [find_weights(need, random, lambda: diffusers_folder(source))]
    if kind == "relighter":
        node = c.model.relighter
        known = _builder(kind, node, f"{c.model.name} relighter")
        if known is not None:
            return [known]
        device, gpu = device_of(node.get("device"), True)
        source = str(node.model_id)
        need = ModelNeed(
            kind, "FLUX.1-Kontext-dev", source, key="model.relighter.model_id", device=device, needs_gpu=gpu
        )
        need.memory_gb, need.family = mem["kontext"], "flux"
        out = [find_weights(need, random, lambda: diffusers_folder(source))]
        lora = node.get("lora")
        if lora:
            from snell_bench.relight.kontext import resolve_lora

            state, where = lookup(lambda: resolve_lora(str(lora))[0])
            fix = f"set {example('relight.lora', str(lora))} (a .safetensors file or a folder), or relight.lora=null"
            out.append(ModelNeed("lora", "relighting LoRA", str(lora), state, where, "relight.lora", fix, device, gpu))
        return out
    if kind == "pipeline":
        described = method_of(c).describe(kind, key, c, basis)
        if described is not None:
            return described
    if kind == "depth":
        node = c.depth.estimator
        known = _builder(kind, node, str(c.depth.name))
        if known is not None:
            return [known]
        device, gpu = device_of(c.depth.device, False)
        source = str(c.depth.path)
        name = str(c.depth.name)
        find = (lambda: _moge_file(source)) if name == "moge2" else (lambda: _transformers_folder(source))
        need = ModelNeed(kind, name, source, key="depth.path", device=device, needs_gpu=gpu)
        need.memory_gb = OTHER_GB.get(name)
        return [find_weights(need, False, find)]
    if kind == "segmenter":
        node = c.segment.segmenter
        known = _builder(kind, node, str(c.segment.name))
        if known is not None:
            return [known]
        device, gpu = device_of(c.segment.device, False)
        source = str(c.segment.path)
        name = str(c.segment.name)
        need = ModelNeed(kind, "SAM 3" if name == "sam3" else name, source, key="segment.path", device=device)
        need.needs_gpu, need.memory_gb = gpu, OTHER_GB.get(name)
        return [find_weights(need, False, lambda: _transformers_folder(source))]
    return [ModelNeed(kind, key[:40], weights="unchecked", where="not known to job=plan")]


def metric_models(metrics: DictConfig) -> list[ModelNeed]:
    """The metric backbones every cell is scored with (:func:`snell_bench.metrics.load_scorers`,
    on the CPU): LPIPS's VGG16, CLIP ViT-B/16, ImageReward's interpreter; a missing one is
    reported as a missing metric, never faked."""
    from snell_bench.metrics.alignment import ImageRewardScorer, resolve_clip_checkpoint
    from snell_bench.metrics.fidelity import _BACKBONE_FILES, MaskedLPIPS

    tv_name, file_name = _BACKBONE_FILES["vgg"]
    lpips = metrics.get("lpips_weights")
    clip = metrics.get("clip_weights")
    python = metrics.get("image_reward_python")
    found = [
        lookup(lambda: MaskedLPIPS._resolve_weights(lpips, file_name, tv_name, False)),
        lookup(lambda: resolve_clip_checkpoint(clip) if clip else _default_clip_checkpoint()),
        lookup(lambda: ImageRewardScorer(python).python),
    ]
    rows = [
        ("lpips", "LPIPS (VGG16)", lpips, "metrics.lpips_weights", f"metrics.lpips_weights=/data/{file_name}"),
        (
            "clip",
            "CLIP ViT-B/16",
            clip,
            "metrics.clip_weights",
            "metrics.clip_weights=/data/open_clip_model.safetensors",
        ),
        (
            "image_reward",
            "ImageReward",
            python,
            "metrics.image_reward_python",
            "metrics.image_reward_python=/env/bin/python",
        ),
    ]
    out = []
    for (kind, name, source, key, shown), (state, where) in zip(rows, found):
        fix = f"set {shown} (else the metric is reported as missing)" if state == "missing" else ""
        out.append(ModelNeed(kind, name, str(source or ""), state, where, key, fix, "cpu", False, None))
    return out


#: Where :func:`~snell_bench.metrics.alignment.resolve_clip_checkpoint` finds ViT-B-16 (openai)
#: without ``metrics.clip_weights``: open_clip's pretrained entry (its Hugging Face repository and
#: file names, then the URL download's file), here without importing open_clip (~4 s).
CLIP_DEFAULT = (
    "timm/vit_base_patch16_clip_224.openai",
    ("open_clip_model.safetensors", "open_clip_pytorch_model.bin"),
    "ViT-B-16.pt",
)


def _default_clip_checkpoint() -> str:
    from huggingface_hub import try_to_load_from_cache

    from snell_bench.metrics.functional import MetricUnavailable

    repo, names, url_file = CLIP_DEFAULT
    for name in names:
        hit = try_to_load_from_cache(repo, name)
        if isinstance(hit, str) and os.path.isfile(hit):
            return hit
    hit = Path("~/.cache/clip").expanduser() / url_file
    if hit.is_file():
        return str(hit)
    raise MetricUnavailable(f"no CLIP weights for ViT-B-16 (openai) on this machine (Hugging Face cache: {repo})")


# ---------------------------------------------------------------------------- time and memory of a cell
def estimate_cell(scene_cfg: DictConfig, method_cfg: DictConfig, models: Sequence[ModelNeed], basis: Basis) -> Estimate:
    """Time and GPU memory of a cell of the scene of ``scene_cfg`` and the method of ``method_cfg``
    (their parts, :class:`GridParts`), the models it needs described in ``models``: what the
    method's kind says it costs (:meth:`snell_bench.methods.Method.cost`), with relighting added
    (:func:`~snell_bench.methods.cost.relight_estimate`)."""
    est = method_of(method_cfg).cost(scene_cfg, method_cfg, models, basis)
    return relight_estimate(est, scene_cfg, method_cfg, models, basis)


# ---------------------------------------------------------------------------- the plan
@dataclass
class MethodTime:
    """Time of one method's cells: per cell (over the scenes, ``low``-``high``) and in total."""

    method: str
    kind: str
    per_cell: tuple[float, float] | None
    cells_left: int
    total: tuple[float, float] | None
    weights_gb: float
    peak_gb: float | None
    basis: str
    note: str


@dataclass
class Plan:
    """What ``job=plan`` prints (:func:`format_plan`); see the module's docs."""

    experiment: str
    root: Path
    model: str
    recipe: str
    scenes: int
    variations: int
    objects: int
    methods: list[str]
    cells: list[CellState]
    models: list[ModelNeed]
    device: DeviceInfo
    times: list[MethodTime]
    basis: Basis
    memory: list[str]
    warnings: list[str]
    compositions: int

    @property
    def groups(self) -> int:
        return self.scenes * self.variations * self.objects

    def counts(self) -> Counter:
        return Counter(c.state for c in self.cells)

    @property
    def left(self) -> list[CellState]:
        return [c for c in self.cells if not c.done]


def make_plan(
    cfg: DictConfig,
    *,
    basis: Basis | None = None,
    device: DeviceInfo | None = None,
    compose_fn: Callable[[list[str]], DictConfig] = compose,
) -> Plan:
    """The plan of ``cfg``'s grid on this machine (see the module's docs); nothing is written.

    Args:
        cfg: the run's config (composed from ``cfg.overrides``, as ``python -m snell_bench`` does).
        basis: the time and memory basis (:func:`load_bench`); ``None``: ``plan.bench`` when set,
            else :data:`README_BASIS`.
        device: the CUDA device to plan for; ``None``: this machine's (:func:`local_device`).
        compose_fn: composes overrides (:func:`snell_bench.config.compose`).

    Raises:
        ConfigError: an unknown or repeated grid entry, or an unusable ``plan.bench``.
        ValueError: ``cfg`` differs from what its overrides compose.
    """
    if basis is None:
        bench = OmegaConf.select(cfg, "plan.bench")
        basis = README_BASIS if bench is None else load_bench(bench)
    device = local_device() if device is None else device
    check_reproducible(cfg)
    problems = check_grid_entries(cfg)
    if problems:
        raise ConfigError(problems)
    parts = GridParts(cfg, compose_fn)
    cells = cell_states(cfg, parts)
    g = cfg.grid

    described: dict[tuple[str, str], list[ModelNeed]] = {}
    per_pair: dict[tuple[str, str], list[ModelNeed]] = {}
    for scene in map(str, g.scenes):
        for method in map(str, g.methods):
            found: list[ModelNeed] = []
            for kind, key in parts.models(scene, method):
                if (kind, key) not in described:
                    src = parts.method(method) if kind in ("fill", "relighter", "pipeline") else parts.scene(scene)
                    described[(kind, key)] = describe_model(kind, key, src, basis)
                found += [m for m in described[(kind, key)] if all(m is not f for f in found)]
            c = parts.method(method)
            if c.model.from_scene and method_of(c).uses_generator(
                c
            ):  # the group's own generator (not the pool's): listed too
                key = ("generator", "from_scene " + node_key(c.model))
                if key not in described:
                    described[key] = describe_model("generator", key[1], c, basis)
                found += described[key]
            per_pair[(scene, method)] = found
    for c in cells:
        for m in per_pair[(c.scene, c.method)]:
            m.cells += 1
            m.cells_left += int(not c.done)
            if c.method not in m.methods:
                m.methods.append(c.method)
    metrics = metric_models(cfg.metrics)
    for m in metrics:
        m.cells, m.cells_left, m.methods = len(cells), sum(not c.done for c in cells), [str(x) for x in g.methods]
    models = [m for ms in described.values() for m in ms] + metrics

    times = []
    for method in g.methods:
        method = str(method)
        rows = []
        for scene in g.scenes:
            est = estimate_cell(parts.scene(str(scene)), parts.method(method), per_pair[(str(scene), method)], basis)
            left = sum(1 for c in cells if c.scene == str(scene) and c.method == method and not c.done)
            rows.append((est, left))
        times.append(_method_time(method, str(parts.method(method).method.kind), rows))
    left_models = {id(m) for m in models if m.cells_left} or {id(m) for m in models}
    memory = memory_plan([m for m in models if id(m) in left_models], cfg.models, device, basis)
    warnings = []
    changed = [c for c in cells if c.state == "changed"]
    if changed and OnChange.of(g.on_change, "grid.on_change") is OnChange.error:
        err = SettingsChanged(
            [ChangedCell(Cell(c.name, c.folder, None, {}), c.diff) for c in changed],
            on_change_key="grid.on_change",
            recompute_key="grid.recompute",
        )
        warnings.append("the grid would stop before any work: " + str(err).replace("\nNothing was run.", ""))
    return Plan(
        experiment=str(cfg.experiment_name),
        root=Path(cfg.runs_dir) / str(cfg.experiment_name),
        model=str(cfg.model.name),
        recipe=str(cfg.recipe),
        scenes=len(g.scenes),
        variations=len(g.variations),
        objects=len(g.objects),
        methods=[str(m) for m in g.methods],
        cells=cells,
        models=models,
        device=device,
        times=times,
        basis=basis,
        memory=memory,
        warnings=warnings,
        compositions=parts.compositions,
    )


def _method_time(method: str, kind: str, rows: list[tuple[Estimate, int]]) -> MethodTime:
    if not rows:
        return MethodTime(method, kind, None, 0, None, 0.0, None, "none", "no cells")
    known = [(e, n) for e, n in rows if e.seconds is not None]
    first = rows[0][0]
    left = sum(n for _, n in rows)
    if len(known) < len(rows):
        return MethodTime(method, kind, None, left, None, first.weights_gb, first.peak_gb, first.basis, first.note)
    per = (min(e.seconds[0] for e, _ in known), max(e.seconds[1] for e, _ in known))
    total = (sum(e.seconds[0] * n for e, n in known), sum(e.seconds[1] * n for e, n in known))
    weights = max(e.weights_gb for e, _ in rows)
    peaks = [e.peak_gb for e, _ in rows if e.peak_gb is not None]
    return MethodTime(method, kind, per, left, total, weights, max(peaks) if peaks else None, first.basis, first.note)


#: GB (10⁹ bytes) in a GiB (``models.memory_gb``'s unit).
GIB = 2**30 / 1e9

#: GB of activations beside a model's weights when no bench measured them: the documented "a few GB
#: of activations at 720 x 1280", taken as 10.
ACTIVATIONS_GB = 10.0


def activations_gb(basis: Basis) -> float:
    """GB a stage holds beside its weights: the largest measured peak less its weights
    (``plan.bench``), else :data:`ACTIVATIONS_GB`."""
    weights = {"pair": "flux_dev", "t2i": "flux_dev", "fill": "fill", "kontext": "kontext"}
    extra = [basis.peak_gb[k] - basis.memory_gb[w] for k, w in weights.items() if k in basis.peak_gb]
    return max(0.0, *extra) if extra else ACTIVATIONS_GB


def memory_plan(models: Sequence[ModelNeed], models_cfg: DictConfig, device: DeviceInfo, basis: Basis) -> list[str]:
    """Lines on the GPU memory of ``models`` (those the cells left need): whether they fit together
    on ``device`` or in ``models.memory_gb``, else the model-major order with offloading."""
    gpu = [m for m in models if m.kind != "lora" and (m.needs_gpu or (m.device == "cuda if available" and device.cuda))]
    if not gpu:
        return ["no model runs on a GPU"]
    known = [m for m in gpu if m.memory_gb is not None]
    together = together_gb(known, basis)
    largest = max(known, key=lambda m: m.memory_gb or 0.0) if known else None
    unknown = [m.name for m in gpu if m.memory_gb is None]
    shared = sum(1 for m in known if m.family == "flux") > 1
    lines = [
        f"GPU weights together: {together:.0f} GB"
        + (
            f" (FLUX.1-dev's text encoders and VAE, {basis.memory_gb['shared_text_vae']:g} GB, counted once)"
            if shared
            else ""
        )
        + (f"; not known: {', '.join(unknown)}" if unknown else "")
        + (f"; largest: {largest.name} {largest.memory_gb:g} GB" if largest else "")
    ]
    act = activations_gb(basis)
    lines.append(
        f"activations: {act:.0f} GB "
        + (
            "(the bench's largest peak less its weights)"
            if basis.peak_gb
            else "(the documented 'a few GB' at 720 x 1280, taken as 10)"
        )
    )
    budget_gib = models_cfg.get("memory_gb")
    offload = bool(models_cfg.get("offload", True))
    where = (
        "host memory (models.offload=true)" if offload else "nowhere: dropped and loaded again (models.offload=false)"
    )
    if device.cuda:
        capacity, what = device.memory_gb, f"{device.name} ({device.memory_gb:.0f} GB)"
    else:
        capacity, what = 80.0, "an 80 GB GPU (no GPU here: the documented reference)"
    if budget_gib is None:
        if together + act <= capacity:
            lines.append(f"they fit together on {what}: group-major order, every model stays loaded")
        else:
            suggest = max(int((capacity - act) / GIB), 1)
            lines.append(
                f"they do not fit together on {what}: set models.memory_gb={suggest} (GiB: the GPU less the "
                "activations) so the grid runs model-major "
                f"(each model loads once, the least recently used one moved to {where})"
            )
    else:
        budget = float(budget_gib) * GIB
        fits = together <= budget
        lines.append(
            f"models.memory_gb={budget_gib:g} GiB ({budget:.0f} GB): model-major order; "
            + (
                "the models fit the budget together"
                if fits
                else f"they do not fit together: each makes room in {where}"
            )
        )
    for m in known:
        gb = m.memory_gb or 0.0
        if device.cuda and gb > device.memory_gb:
            lines.append(f"{m.name} ({gb:g} GB) is larger than {what}: it cannot load there")
        elif not device.cuda and gb > 80.0:
            lines.append(f"{m.name} ({gb:g} GB) is larger than an 80 GB GPU: it needs a larger one (e.g. 141 GB)")
        elif budget_gib is not None and gb > float(budget_gib) * GIB:
            lines.append(f"{m.name} ({gb:g} GB) is larger than models.memory_gb: the pool loads it alone")
    return lines


# ---------------------------------------------------------------------------- printing
def _table(rows: list[dict]) -> str:
    """``rows`` as an indented text table: a column per key, numbers right-aligned, text left-aligned."""
    if not rows:
        return "  (none)"
    cols = list(rows[0])
    cells = [[str(r.get(c, "")) for c in cols] for r in rows]
    width = [max(len(c), *(len(row[i]) for row in cells)) for i, c in enumerate(cols)]
    numeric = [all(isinstance(r.get(c), (int, float)) for r in rows) for c in cols]

    def line(values: list[str]) -> str:
        return "  " + "  ".join(v.rjust(w) if n else v.ljust(w) for v, w, n in zip(values, width, numeric)).rstrip()

    return "\n".join([line(cols), *(line(row) for row in cells)])


_STATE_WORDS = {
    "done": "done",
    "skipped": "skipped (done)",
    "changed": "other settings",
    "files": "files changed",
    "failed": "failed before",
    "new": "not run",
    "recompute": "grid.recompute",
}


def format_plan(plan: Plan) -> str:
    """The plan as the text ``job=plan`` prints."""
    out = []
    counts = plan.counts()
    done = counts["done"] + counts["skipped"]
    out.append(f"job=plan: experiment {plan.experiment} -> {plan.root} (nothing written, nothing downloaded)")
    out.append(f"  model={plan.model}, recipe={plan.recipe}")
    out.append(
        f"grid: {plan.scenes} scenes x {plan.variations} variations x {plan.objects} objects = {plan.groups} groups; "
        f"x {len(plan.methods)} methods = {len(plan.cells)} cells"
    )
    parts = ", ".join(f"{counts[s]} {_STATE_WORDS[s]}" for s in _STATE_WORDS if counts[s] and s not in ("done",))
    out.append(f"cells: {done} done, {len(plan.left)} left" + (f" ({parts})" if parts else ""))
    rows = []
    for m in plan.methods:
        mine = Counter(c.state for c in plan.cells if c.method == m)
        row = {"method": m, "cells": sum(mine.values())}
        row.update({_STATE_WORDS[s]: mine[s] for s in _STATE_WORDS if counts[s]})
        row["left"] = sum(n for s, n in mine.items() if s not in ("done", "skipped"))
        rows.append(row)
    out.append(_table(rows))
    for w in plan.warnings:
        out.append("WARNING: " + w)

    gpu_models = [m.name for m in plan.models if m.needs_gpu and m.cells_left]
    if plan.device.cuda:
        dev = f"{plan.device.name}, {plan.device.memory_gb:.0f} GB" + (
            f" (x{plan.device.count})" if plan.device.count > 1 else ""
        )
        out.append(f"device: CUDA {dev}" + (f"; needed by {', '.join(gpu_models)}" if gpu_models else ""))
    elif gpu_models:
        out.append(
            f"device: no CUDA GPU here (torch.cuda.is_available() is False); the cells left need one for "
            f"{', '.join(gpu_models)} (model.device: null = CUDA; model.device=cpu runs them on the CPU)"
        )
    else:
        out.append("device: no CUDA GPU here, and none is needed")

    out.append("models (weights looked up in local folders and the Hugging Face cache only):")
    rows = [
        {
            "kind": m.kind,
            "model": m.name,
            "source": _short(m.source),
            "methods": ",".join(m.methods) if len(m.methods) < len(plan.methods) else "all",
            "cells left": m.cells_left,
            "device": m.device,
            "GB": "—" if m.memory_gb is None else f"{m.memory_gb:g}" + ("*" if m.family == "flux" else ""),
            "weights": m.weights,
        }
        for m in plan.models
    ]
    out.append(_table(rows))
    if any(m.family == "flux" for m in plan.models):
        shared = plan.basis.memory_gb["shared_text_vae"]
        out.append(f"  * FLUX.1-dev, Fill and Kontext share the text encoders and VAE ({shared:g} GB of each)")
    missing = [m for m in plan.models if m.weights == "missing"]
    for m in missing:
        out.append(f"  MISSING {m.name}: {m.where}; {m.fix}")
    out += [f"  {m.name}: {m.where}" for m in plan.models if m.weights in ("random", "unchecked")]
    out.append("memory:")
    out += ["  " + line for line in plan.memory]

    out.append("time (per cell, over the scenes, and in total):")
    rows = [
        {
            "method": t.method,
            "kind": t.kind,
            "per cell": secs(t.per_cell),
            "cells left": t.cells_left,
            "total": secs(t.total) if t.cells_left else "0",
            "GPU GB": f"{t.weights_gb:.0f}" if t.weights_gb else "0",
            "peak GB": "—" if t.peak_gb is None else f"{t.peak_gb:.0f}",
            "basis": t.basis,
        }
        for t in plan.times
    ]
    out.append(_table(rows))
    labels = {"README": README_LABEL, "bench": plan.basis.label, "CPU": CPU_LABEL}
    for b in dict.fromkeys(t.basis for t in plan.times):
        if b in labels:
            out.append(f"  {b}: {labels[b]}")
    notes: dict[str, list[str]] = {}
    for t in plan.times:
        notes.setdefault(t.note, []).append(t.method)
    for note, methods in notes.items():
        out.append(f"  {', '.join(methods)}: {note}")
    known = [t for t in plan.times if t.total is not None and t.cells_left]
    unknown = [t for t in plan.times if t.total is None and t.cells_left]
    line = f"total: {sum(t.cells_left for t in plan.times)} cells left"
    if known:
        total = (sum(t.total[0] for t in known), sum(t.total[1] for t in known))
        bases = " + ".join(dict.fromkeys(t.basis for t in known))
        line += f"; {sum(t.cells_left for t in known)} estimated: {secs(total)} ({bases})"
    if unknown:
        line += "; not estimated: " + ", ".join(f"{t.method} ({t.cells_left} cells)" for t in unknown)
    out.append(line)
    if any(t.basis in ("README", "bench") for t in known):
        out.append(
            "  not included: model loads (each model once per sweep), each group's inputs on the CPU (warps and the "
            "reference render; docs/gpu.md, paper preset on 2 cores: 2.6 s + 36.5 s per group)"
        )
    return "\n".join(out)


def _short(text: str, n: int = 48) -> str:
    text = str(text)
    return text if len(text) <= n else "..." + text[-(n - 3) :]


def run_plan(cfg: DictConfig) -> Plan:
    """``job=plan``: print the plan of ``cfg`` (:func:`make_plan`, :func:`format_plan`)."""
    plan = make_plan(cfg)
    print(format_plan(plan))
    return plan
