"""`python -m pipeline [overrides]`: the Hydra app that runs the BIRL-G pipeline stages."""

from __future__ import annotations

import json
import logging
import sys
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import DictConfig

from pipeline.app.config import register_configs
from pipeline.errors import PipelineError
from pipeline.stages import run_pipeline

register_configs()


@hydra.main(version_base="1.3", config_path="../conf", config_name="config")
def main(cfg: DictConfig) -> None:
    hydra_cfg = HydraConfig.get()
    run_dir = Path(hydra_cfg.runtime.output_dir)
    if hydra_cfg.mode != RunMode.MULTIRUN:
        try:
            run_pipeline(cfg, run_dir)
        except PipelineError as e:
            # One clear line and a non-zero exit; SystemExit passes through Hydra untouched.
            print(f"error: {e}", file=sys.stderr)
            sys.exit(2)
        return
    # In a sweep a failing job must not stop the others: record the failure in the job's
    # dir (status.json, read by `make aggregate`, whose exit status reports it) and return.
    status = {"ok": True, "error": None}
    try:
        run_pipeline(cfg, run_dir)
    except Exception as e:  # noqa: BLE001 - any failure of one job, reported per job
        status = {"ok": False, "error": f"{type(e).__name__}: {e}" if not isinstance(
            e, PipelineError) else str(e)}
        logging.getLogger("pipeline").error("job failed: %s", status["error"],
                                            exc_info=not isinstance(e, PipelineError))
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "status.json").write_text(json.dumps(status))


if __name__ == "__main__":
    main()
