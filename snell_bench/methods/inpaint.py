"""``method.kind=inpaint``: the object's region of I⁻ repainted from the object phrase: FLUX Fill
(``model.fill``), or without one the generator's CPU stand-in (its image pasted into the region,
no optics)."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from omegaconf import DictConfig

from snell_bench.methods.base import Method
from snell_bench.methods.cost import Basis, Estimate, ModelNeed, fill_estimate, sampler_estimate
from snell_bench.methods.pipeline import pipeline_call
from snell_bench.methods.snellcaster import generator_models, synchronized
from snell_bench.optics.warps import WarpSet
from snell_bench.pipeline.cell import CellInputs, CellResult, node_key
from snell_bench.pipeline.methods import inpaint_mask
from snell_bench.utils.timing import Timer

__all__ = ["Inpaint"]


class Inpaint(Method):
    """FLUX Fill of the region :func:`~snell_bench.pipeline.methods.inpaint_mask` names
    (``method.mask``, ``method.mask_dilate_px``), or its CPU stand-in."""

    kind = "inpaint"
    description = "the object's region of I⁻ repainted (FLUX Fill, or the generator's image pasted on the CPU)"

    def models(self, cfg: DictConfig) -> list[tuple[str, str]]:
        return [("fill", node_key(cfg.model.fill))] if cfg.model.get("fill") else generator_models(cfg)

    def uses_generator(self, cfg: DictConfig) -> bool:
        return not cfg.model.get("fill")

    def run(self, cfg: DictConfig, inputs: CellInputs, warps: WarpSet, t: Timer) -> CellResult:
        if cfg.model.get("fill"):
            return pipeline_call(cfg, inputs, warps, t, fill=True)
        res = synchronized(cfg, inputs, warps, t, baseline=True)
        res.image = torch.where(torch.from_numpy(inpaint_mask(cfg, warps))[None, None], res.image, inputs.i_minus)
        return res

    def cost(self, scene_cfg: DictConfig, cfg: DictConfig, models: Sequence[ModelNeed], basis: Basis) -> Estimate:
        if cfg.model.get("fill"):
            return fill_estimate(scene_cfg, cfg, models, basis)
        return sampler_estimate(scene_cfg, cfg, models, basis, full=False)
