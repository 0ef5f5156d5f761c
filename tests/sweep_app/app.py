"""A sweep job that holds while ``<sweep dir>/hold-<job>`` exists, then writes a complete run record.

Used by tests/test_sweeps.py to kill or interrupt a job at a known moment:
the job writes its process id to ``<job dir>/pid`` as soon as it starts.
"""

import json
import os
import time
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import OmegaConf


@hydra.main(version_base="1.3", config_path=".", config_name="config")
def app(cfg) -> None:
    from hydra_plugins.icgo_launcher.jobs import config_hash
    from icgo.reporting import records as R

    hc = HydraConfig.get()
    out = Path(hc.runtime.output_dir)
    (out / "pid").write_text(str(os.getpid()))
    hold = Path(hc.sweep.dir) / f"hold-{cfg.job}"
    t_end = time.monotonic() + 120
    while hold.exists() and time.monotonic() < t_end:
        time.sleep(0.05)
    run = {k: None for k in R.RUN_KEYS} | {"status": "ok", "label": cfg.job,
                                           "xla_flags": os.environ.get("XLA_FLAGS", ""),
                                           "affinity": sorted(os.sched_getaffinity(0)),
                                           # the config it ran, as experiments.run records it (a re-run keeps it)
                                           "config_sha256": config_hash(OmegaConf.to_container(cfg, resolve=True))}
    (out / R.RUN_FILE).write_text(json.dumps(run))


if __name__ == "__main__":
    app()
