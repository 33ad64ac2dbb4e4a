"""``method.kind=snellcaster``: the synchronized sampler (the paper's method and its ablations).

The generator samples the image and a 360° panorama centred on the object together, warping and
blending their clean-image estimates with the warped I⁻ at every step
(:func:`~snell_bench.sampler.snellcaster.sample` with the ``sampler`` node, the method's switches
applied). :func:`synchronized` is shared with the baselines that sample with the same generator
(``t2i``, the ``inpaint`` stand-in).
"""

from __future__ import annotations

from collections.abc import Sequence

from omegaconf import DictConfig, OmegaConf

from snell_bench.config import SamplerSettings
from snell_bench.methods.base import Method
from snell_bench.methods.cost import Basis, Estimate, ModelNeed, sampler_estimate
from snell_bench.optics.warps import WarpSet
from snell_bench.pipeline.cell import CellInputs, CellResult, cell_seed, full_prompt, node_key
from snell_bench.pipeline.methods import baseline_prompt, cell_generator
from snell_bench.sampler.snellcaster import sample
from snell_bench.utils.timing import Timer

__all__ = ["Snellcaster", "synchronized", "generator_models"]


def generator_models(cfg: DictConfig) -> list[tuple[str, str]]:
    """The pool's generator a sampling method uses: ``model.generator``, shared by the sweep; none
    for a generator built from the scene (the group's own)."""
    return [] if cfg.model.from_scene else [("generator", node_key(cfg.model))]


def synchronized(cfg: DictConfig, inputs: CellInputs, warps: WarpSet, t: Timer, *, baseline: bool) -> CellResult:
    """The sampler with the ``sampler`` node on the cell's generator: the full prompt p, or for a
    ``baseline`` its own prompt (:func:`~snell_bench.pipeline.methods.baseline_prompt`) and steps
    (``method.steps``). The result keeps the model calls, the sampler's stage times and its
    decisions in ``stats``."""
    gen, t.seconds["generator"] = cell_generator(cfg, inputs)
    settings = OmegaConf.to_object(cfg.sampler)
    assert isinstance(settings, SamplerSettings)
    prompt = full_prompt(cfg)
    if baseline:  # a baseline: its prompt and steps (baselines node)
        prompt = baseline_prompt(cfg)
        if cfg.method.steps is not None:
            settings.steps = cfg.method.steps
    with t("sampling"):
        res = sample(gen, warps, inputs.i_minus, prompt, cfg.scene.pano_prompt, settings, seed=cell_seed(cfg))
    stats = {
        "model_calls": res.model_calls,
        "sampler_timings_s": {k: round(v, 3) for k, v in res.timings.items()},
        "decisions": res.decisions,
    }
    return CellResult(image=res.image, panorama=res.panorama, stats=stats, dumps=res.dumps, warps=warps)


class Snellcaster(Method):
    """The synchronized sampler (``sampler.sync=snellcaster``; its ablations switch parts off)."""

    kind = "snellcaster"
    description = "the synchronized sampler: the image and its panorama, warped and blended with I⁻ at every step"

    def models(self, cfg: DictConfig) -> list[tuple[str, str]]:
        return generator_models(cfg)

    def uses_generator(self, cfg: DictConfig) -> bool:
        return True

    def run(self, cfg: DictConfig, inputs: CellInputs, warps: WarpSet, t: Timer) -> CellResult:
        return synchronized(cfg, inputs, warps, t, baseline=False)

    def cost(self, scene_cfg: DictConfig, cfg: DictConfig, models: Sequence[ModelNeed], basis: Basis) -> Estimate:
        return sampler_estimate(scene_cfg, cfg, models, basis, full=True)
