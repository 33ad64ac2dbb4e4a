"""``python -m snell_bench``: the Hydra entry point. Jobs live in :mod:`snell_bench.experiment`."""

from __future__ import annotations

import hydra
from omegaconf import DictConfig

from snell_bench.config import register_configs

register_configs()
CONFIG_DIR = "conf"


@hydra.main(version_base="1.3", config_path=CONFIG_DIR, config_name="config")
def main(cfg: DictConfig) -> None:
    from hydra.core.hydra_config import HydraConfig

    from snell_bench.experiment import run_job

    cfg.overrides = list(HydraConfig.get().overrides.task)  # a sweep composes its cells from them
    run_job(cfg)


if __name__ == "__main__":
    main()
