"""``method.kind=external``: another text-to-image model as a diffusers pipeline (FLUX.2-dev,
Qwen-Image, SD3.5-Large in the paper's Table 1), from ``method.model_id`` (a Hugging Face id in
the local cache, or a local folder), with the method's steps, guidance and prompt; a model's
``pipelines`` builder (the tiny random stand-ins) builds it by ``method.architecture`` instead.

Another diffusers model needs one method YAML and nothing else: its ``model_id``, its label, and
for ``job=plan`` its documented figures under ``method.cost`` (seconds per image at 720 x 1280 on
an 80 GB GPU, bf16 weights in GB, the pipeline's default steps).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from snell_bench.methods.base import Method
from snell_bench.methods.cost import (
    Basis,
    Estimate,
    ModelNeed,
    device_of,
    diffusers_folder,
    example,
    find_weights,
    ratio_note,
    scaled,
    together_gb,
)
from snell_bench.models.errors import DeviceNotAvailableError, WeightsNotFoundError
from snell_bench.models.external import generate_external, inpaint_external, load_pipeline
from snell_bench.models.sizes import node_weights_bytes
from snell_bench.optics.warps import WarpSet
from snell_bench.pipeline.cell import CellInputs, CellResult, Skip, build, cell_seed, node_key
from snell_bench.pipeline.methods import architecture, baseline_prompt, inpaint_mask
from snell_bench.utils.timing import Timer

__all__ = ["DiffusersPipeline", "pipeline_call"]


def _pipeline(cfg: DictConfig, inputs: CellInputs, t: Timer, *, fill: bool):
    """The diffusers pipeline of the cell from the inputs' pool: the model's stand-ins
    (``model.pipelines``), ``method.model_id``, or FLUX Fill (``model.fill``)."""
    pool = inputs.pool
    device, dtype = cfg.model.device, cfg.model.dtype
    if fill:
        pipe, t.seconds["generator"] = pool.get(
            "fill",
            node_key(cfg.model.fill),
            lambda: build(cfg.model.fill),
            label=f"{cfg.model.name} fill",
            size=lambda: node_weights_bytes(cfg.model.fill),
        )
    elif cfg.model.get("pipelines"):  # the model's stand-ins (tiny random pipelines)
        pipe, t.seconds["generator"] = pool.get(
            "pipeline",
            f"{node_key(cfg.model.pipelines)}:{cfg.method.architecture}",
            lambda: build(cfg.model.pipelines, kind=architecture(cfg)),
            label=f"{cfg.model.name} {cfg.method.architecture}",
        )
    else:
        key = node_key(OmegaConf.create({"model_id": cfg.method.model_id, "device": device, "dtype": dtype}))
        pipe, t.seconds["generator"] = pool.get(
            "pipeline",
            key,
            lambda: load_pipeline(cfg.method.model_id, device=device, dtype=dtype, memory_gb=cfg.models.memory_gb),
            label=str(cfg.method.model_id),
        )
    return pipe


def pipeline_call(cfg: DictConfig, inputs: CellInputs, warps: WarpSet, t: Timer, *, fill: bool = False) -> CellResult:
    """A baseline that is a diffusers pipeline: another text-to-image model (``external``, from
    ``method.model_id``) or FLUX Fill (``fill``: the ``inpaint`` kind with ``model.fill``), with the
    method's steps, guidance and prompt, seeded with the cell's seed, on ``model.device``. Missing
    weights or device: :class:`~snell_bench.pipeline.Skip` with the reason."""
    text = baseline_prompt(cfg)
    steps = cfg.method.steps
    guidance = cfg.method.guidance
    try:
        pipe = _pipeline(cfg, inputs, t, fill=fill)
        with t("sampling"):
            if fill:
                img, used = inpaint_external(
                    pipe,
                    text,
                    inputs.i_minus,
                    inpaint_mask(cfg, warps),
                    seed=cell_seed(cfg),
                    steps=steps,
                    guidance=guidance,
                    return_settings=True,
                )
            else:
                img, used = generate_external(
                    pipe,
                    text,
                    warps.camera.shape,
                    seed=cell_seed(cfg),
                    steps=steps,
                    guidance=guidance,
                    return_settings=True,
                    cfg=bool(cfg.method.get("cfg", True)),
                )
    except (WeightsNotFoundError, DeviceNotAvailableError) as e:
        raise Skip(f"{cfg.method.label} cannot run here: {e}") from None
    return CellResult(image=img, warps=warps, stats={"pipeline": {**used.as_dict(), "prompt": text}})


class DiffusersPipeline(Method):
    """Another text-to-image model through diffusers (see the module's docs)."""

    kind = "external"
    description = "another text-to-image model as a diffusers pipeline (method.model_id)"

    def models(self, cfg: DictConfig) -> list[tuple[str, str]]:
        return [("pipeline", str(cfg.method.model_id))]

    def run(self, cfg: DictConfig, inputs: CellInputs, warps: WarpSet, t: Timer) -> CellResult:
        return pipeline_call(cfg, inputs, warps, t)

    def describe(self, kind: str, key: str, cfg: DictConfig, basis: Basis) -> list[ModelNeed] | None:
        if kind != "pipeline":
            return None
        source = str(cfg.method.model_id)
        device, gpu = device_of(cfg.model.device, True)
        gb = cfg.method.cost.weights_gb
        need = ModelNeed(
            kind,
            cfg.method.label,
            source,
            key="method.model_id",
            device=device,
            needs_gpu=gpu,
            memory_gb=None if gb is None else float(gb),
        )
        need = find_weights(need, False, lambda: diffusers_folder(source))
        if need.weights == "missing":
            where = Path("snell_bench/conf/method") / f"{cfg.method.name}.yaml"
            need.fix = (
                f"set {example('method.model_id', source)} in {where} (on the command line it would set every "
                f"method's), or put {source} in the Hugging Face cache"
            )
        return [need]

    def cost(self, scene_cfg: DictConfig, cfg: DictConfig, models: Sequence[ModelNeed], basis: Basis) -> Estimate:
        """The documented figure (``method.cost``) x pixels (x steps where ``method.steps`` is set),
        on the GPU only."""
        label = cfg.method.label
        weights = together_gb([m for m in models if m.needs_gpu], basis)
        seconds, default_steps = cfg.method.cost.seconds, cfg.method.cost.steps
        pipe = next((m for m in models if m.kind == "pipeline"), None)
        if seconds is None or default_steps is None or pipe is None or not pipe.needs_gpu:
            why = (
                "on the CPU (model.device=cpu): no basis"
                if pipe is not None and not pipe.needs_gpu
                else "no time in the documented basis (set method.cost.seconds and method.cost.steps: seconds per "
                "image at 720x1280 on an 80 GB GPU and the pipeline's default steps)"
            )
            return Estimate(None, weights, None, "none", f"{label}: {why}")
        H, W = scene_cfg.scene.height, scene_cfg.scene.width
        steps = default_steps if cfg.method.steps is None else cfg.method.steps
        ratio = H * W / (720 * 1280) * steps / int(default_steps)
        note = f"README: {label} {float(seconds):g} s at 720x1280, {int(default_steps)} steps" + ratio_note(ratio)
        return Estimate(scaled((float(seconds), float(seconds)), ratio), weights, None, "README", note)
