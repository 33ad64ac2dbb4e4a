"""``snell-bench`` and ``python -m snell_bench``: the Hydra entry point (:func:`cli`). Jobs live in
:mod:`snell_bench.experiment`; ``--help`` lists them (:mod:`snell_bench.config.help`)."""

from __future__ import annotations

import re
import sys

import hydra
from omegaconf import DictConfig

from snell_bench.config import register_configs
from snell_bench.config.help import register_help

register_configs()
register_help()
CONFIG_DIR = "conf"

_SHARDS = re.compile(r"^\+*grid\.shards=(\d+)$")


def shard_sweep(argv: list[str]) -> list[str]:
    """``argv`` with ``grid.shard=range(0,N)`` added when it sweeps (``-m``), sets
    ``grid.shards=N`` and does not choose shards itself: one job per shard (a Slurm job array).

    Examples:
        >>> shard_sweep(["-m", "+experiment=smoke", "grid.shards=2", "--cfg", "hydra"])
        ['-m', '+experiment=smoke', 'grid.shards=2', 'grid.shard=range(0,2)', '--cfg', 'hydra']
        >>> shard_sweep(["+experiment=smoke", "grid.shards=2"])  # a single run: every group
        ['+experiment=smoke', 'grid.shards=2']
    """
    if not any(a in ("-m", "--multirun") for a in argv) or any(a.lstrip("+").startswith("grid.shard=") for a in argv):
        return list(argv)
    at = [i for i, a in enumerate(argv) if _SHARDS.match(a)]
    if not at or int(_SHARDS.match(argv[at[-1]]).group(1)) < 2:
        return list(argv)
    i = at[-1]  # beside it: Hydra's parser takes the overrides as one positional run
    return [*argv[: i + 1], f"grid.shard=range(0,{int(_SHARDS.match(argv[i]).group(1))})", *argv[i + 1 :]]


@hydra.main(version_base="1.3", config_path=CONFIG_DIR, config_name="config")
def main(cfg: DictConfig) -> None:
    from hydra.core.hydra_config import HydraConfig

    from snell_bench.experiment import run_job

    cfg.overrides = list(HydraConfig.get().overrides.task)  # a sweep composes its cells from them
    run_job(cfg)


def cli() -> None:
    """The ``snell-bench`` command (``python -m snell_bench``): Hydra's command line, with a sharded
    sweep's ``grid.shard=range(0,N)`` added (:func:`shard_sweep`). A command of its own is what Hydra's
    shell completion needs (``eval "$(snell-bench -sc install=bash)"``)."""
    sys.argv[1:] = shard_sweep(sys.argv[1:])
    main()


if __name__ == "__main__":
    cli()
