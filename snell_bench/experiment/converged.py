"""Scores against a converged reference (``grid.converged_spp``): fidelity that does not move
with ``reference.spp``.

A cell's own reference is rendered with its ``reference.spp``; a sweep that varies that count (or
any other cost knob) also scores every cell against one reference of many samples per pixel,
rendered once per scene, object, resolution and reference settings (:func:`converged_key`) and
kept in ``<group>/_shared/converged-<key>/`` (``reference.npy``, ``metric_mask.npy``), so a
resumed sweep reads it back. The scores are the cell's metrics ``psnr_converged``,
``mae_converged`` and ``lpips_converged`` (:data:`CONVERGED_METRICS`), with a reason under
``missing`` where one has no value; they are an evaluation on top, not part of the cell's cost
(not in its timings).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from omegaconf import DictConfig

from snell_bench import pipeline
from snell_bench.pipeline.cell import plain
from snell_bench.reports.tradeoff import CONVERGED_METRICS
from snell_bench.utils.io import json_hash, save_npy

__all__ = ["CONVERGED_METRICS", "Converged", "ConvergedReferences", "converged_key"]


def converged_key(c: DictConfig, spp: int) -> str:
    """What a converged reference depends on: the scene (and what makes a generated one: model,
    depth, segment), the object, the background mesh's cut, the reference settings with ``spp``
    replaced, and the seed; SHA-256, 16 hex digits."""

    return json_hash(
        {
            "model": plain(c.model),
            "depth": plain(c.depth),
            "segment": plain(c.segment),
            "scene": plain(c.scene),
            "object": plain(c.object),
            "edge_threshold": c.warps.edge_threshold,
            "reference": dict(plain(c.reference), spp=int(spp)),
            "seed": c.seed,
        }
    )


@dataclass
class Converged:
    """A converged reference: what :func:`snell_bench.pipeline.score` takes as ``reference``."""

    image: np.ndarray  #: (H, W, 3) float32 sRGB in [0, 1]
    mask: np.ndarray  #: (H, W) bool, the metric mask
    spp: int
    key: str


@dataclass
class ConvergedReferences:
    """The converged references of one sweep, ``spp`` samples per pixel, rendered once each."""

    spp: int
    _cache: dict = field(default_factory=dict)

    def get(self, cfg: DictConfig, inputs: pipeline.CellInputs, group_dir: Path) -> Converged | None:
        """The converged reference of a cell's config and inputs: cached, read from its files
        (resume), or rendered and saved under ``group_dir/_shared/converged-<key>/``; ``None``
        where the renderer gives none."""
        key = converged_key(cfg, self.spp)
        if key not in self._cache:
            d = Path(group_dir) / "_shared" / f"converged-{key}"
            if (d / "reference.npy").is_file() and (d / "metric_mask.npy").is_file():
                self._cache[key] = Converged(
                    np.load(d / "reference.npy"), np.load(d / "metric_mask.npy"), self.spp, key
                )
            else:
                ref, _ = pipeline.render_reference(cfg, inputs.scene, inputs.obj, spp=self.spp)
                if ref is None:
                    return None
                conv = Converged(np.asarray(ref.image, np.float32), np.asarray(ref.mask, bool), self.spp, key)
                d.mkdir(parents=True, exist_ok=True)
                save_npy(d / "reference.npy", conv.image)
                save_npy(d / "metric_mask.npy", conv.mask)
                self._cache[key] = conv
        return self._cache[key]

    def score(self, cfg: DictConfig, inputs: pipeline.CellInputs, image, scorers, group_dir: Path) -> dict:
        """``{"metrics": {...}, "missing": {...}, "converged_reference": {spp, key} | None}`` of
        ``image`` against the converged reference (:data:`CONVERGED_METRICS`)."""
        names = [f"{k}_converged" for k in CONVERGED_METRICS]
        conv = self.get(cfg, inputs, group_dir) if cfg.reference.enabled else None
        if conv is None:
            why = f"no converged reference: {inputs.reference_reason}"
            return {"metrics": {}, "missing": dict.fromkeys(names, why), "converged_reference": None}
        scored = pipeline.score(cfg, inputs, image, scorers, reference=conv)
        metrics = {f"{k}_converged": scored["metrics"].get(k) for k in CONVERGED_METRICS}
        missing = {
            f"{k}_converged": scored["missing"].get(k, "no value")
            for k in CONVERGED_METRICS
            if scored["metrics"].get(k) is None
        }
        return {"metrics": metrics, "missing": missing, "converged_reference": {"spp": conv.spp, "key": conv.key}}
