"""One process of a two-process ``jax.distributed`` job on this machine (tests/test_distributed.py).

Run as ``ICGO_COORDINATOR=127.0.0.1:PORT ICGO_NUM_PROCESSES=2 ICGO_PROCESS_ID=i python tests/distributed_app.py OUT
CACHE``: joins the job (:func:`icgo.core.devices.start_distributed`, one CPU device per process), runs the tiny study
of tests/test_parallel.py with its search sharded over both processes' devices, and (process 0) saves the searched
thetas, curves and test metrics to OUT (.npz) with the plan it ran.
"""

import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from icgo.core.devices import start_distributed, use_host_devices  # noqa: E402

request = start_distributed()
use_host_devices(1)

import jax  # noqa: E402
import numpy as np  # noqa: E402

import icgo  # noqa: F401, E402
from icgo.studies.icgo_relm import study  # noqa: E402
from icgo.studies.icgo_relm.config import StudyConfig  # noqa: E402
from tests.test_study import sim_frame  # noqa: E402

jax.config.update("jax_compilation_cache_dir", sys.argv[2])
cfg = StudyConfig(split=dict(n_repeats=3, seed=2), model=dict(hidden=10), budget=dict(pop_size=6, iterations=3),
                  optimizer="cgo", strategies=("original", "wavelet"))
timings = {}
res = study.run_study(sim_frame(), cfg, timings=timings)
if jax.process_index() == 0:
    test = res.metrics.query("split == 'test'").sort_values(["method", "repeat"])
    np.savez(sys.argv[1], theta=res.model.params.theta, curve=res.curves["best_fitness"], mae=test.mae.to_numpy(),
             plan=json.dumps({**timings["execution"], "request": request, "devices_seen": len(jax.devices())}))
jax.distributed.shutdown()
