"""The smallest grid run the end-to-end tests share: ``+experiment=smoke`` at 96 x 64, a few
sampler steps and reference samples, everything written under one folder."""

from pathlib import Path

from snell_bench.config import compose

#: Overrides that make a smoke cell take a few seconds on a CPU.
TINY = [
    "scene.width=96",
    "scene.height=64",
    "warps.pano_height=32",
    "warps.cache_dir=null",
    "sampler.steps=4",
    "reference.spp=2",
    "reference.true_spp=1",
]


def smoke_cfg(root: Path, *more: str):
    """The smoke experiment at :data:`TINY` cost, its runs, reports and output under ``root``."""
    return compose(
        [
            "+experiment=smoke",
            *TINY,
            f"runs_dir={root / 'runs'}",
            f"reports_dir={root / 'reports'}",
            f"output_dir={root}",
            *more,
        ]
    )
