"""``method.kind=t2i``: the generator alone, from the baseline's prompt (no optics; FLUX-dev in the
paper's Table 1)."""

from __future__ import annotations

from collections.abc import Sequence

from omegaconf import DictConfig

from snell_bench.methods.base import Method
from snell_bench.methods.cost import Basis, Estimate, ModelNeed, sampler_estimate
from snell_bench.methods.snellcaster import generator_models, synchronized
from snell_bench.optics.warps import WarpSet
from snell_bench.pipeline.cell import CellInputs, CellResult
from snell_bench.utils.timing import Timer

__all__ = ["TextToImage"]


class TextToImage(Method):
    """The model's generator without synchronisation (``sampler.sync=none``), from the baseline's
    prompt and steps (``baselines``)."""

    kind = "t2i"
    description = "the generator alone from the prompt (no optics)"

    def models(self, cfg: DictConfig) -> list[tuple[str, str]]:
        return generator_models(cfg)

    def uses_generator(self, cfg: DictConfig) -> bool:
        return True

    def run(self, cfg: DictConfig, inputs: CellInputs, warps: WarpSet, t: Timer) -> CellResult:
        return synchronized(cfg, inputs, warps, t, baseline=True)

    def cost(self, scene_cfg: DictConfig, cfg: DictConfig, models: Sequence[ModelNeed], basis: Basis) -> Estimate:
        return sampler_estimate(scene_cfg, cfg, models, basis, full=False)
