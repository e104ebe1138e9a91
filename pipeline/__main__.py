"""`python -m pipeline [overrides]`: the Hydra app that runs the BIRL-G pipeline stages."""

from __future__ import annotations

import sys
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig

from pipeline.config import register_configs
from pipeline.errors import PipelineError
from pipeline.run import run_pipeline

register_configs()


@hydra.main(version_base="1.3", config_path="../conf", config_name="config")
def main(cfg: DictConfig) -> None:
    try:
        run_pipeline(cfg, Path(HydraConfig.get().runtime.output_dir))
    except PipelineError as e:
        # One clear line and a non-zero exit; SystemExit passes through Hydra untouched.
        print(f"error: {e}", file=sys.stderr)
        sys.exit(2)


if __name__ == "__main__":
    main()
