"""experiments.run: Hydra composition, outputs, presets, one-line errors, progress, multirun failures.

Studies here use Hydra's compose API with tiny budgets (population 8, 3
iterations) on a small lab_casing recording written once to a CSV; nothing
depends on the working directory.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import OmegaConf, open_dict

from experiments import _preflight as E
from hydra_plugins.icgo_launcher.jobs import FAILED
from icgo.studies.icgo_relm.run_config import RunConfig
from hydra_plugins.icgo_launcher.jobs import cfg_hash
from hydra_plugins.icgo_launcher import report as sweep_report
from experiments._study_main import run_job
from icgo.optim.registry import get

ROOT = Path(__file__).resolve().parent.parent


def _compose(overrides, hydra=False):
    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=str(E.CONF_DIR), version_base="1.3"):
        cfg = compose(config_name="config", overrides=list(overrides), return_hydra_config=hydra)
    return cfg


def _run_config(cfg):
    """The door's typed config of a composed config (``hydra`` node excluded)."""
    return RunConfig.from_mapping(OmegaConf.to_container(cfg, resolve=True))


def _study(cfg):
    """The StudyConfig a composed config gives (through its typed config)."""
    return _run_config(cfg).study_config()


def _job_cfg(overrides):
    """Config as the task function sees it (HydraConfig set, hydra node removed)."""
    cfg = _compose(overrides, hydra=True)
    HydraConfig.instance().set_config(cfg)
    with open_dict(cfg):
        del cfg["hydra"]
    return cfg


@pytest.fixture(scope="module")
def small_csv(tmp_path_factory):
    """lab_casing with a 30 deg toolface step (8 x 13 rows) as a contract CSV + meta."""
    from icgo.datasets import casing_stations
    from icgo.io.recording import write_recording

    ds = casing_stations.lab_casing(0, toolface_step_deg=30.0)
    path = tmp_path_factory.mktemp("data") / "lab_small.csv"
    write_recording(path, ds.frame, {k: v for k, v in ds.meta.items() if k in
                                     ("total_field_nT", "dip_deg", "declination_deg", "gravity_g", "name")})
    return path


TINY = ["budget=smoke", "progress=false", "figures=false", "jax_cache_dir=null"]


def test_default_config_is_the_paper_protocol():
    cfg = _compose([])
    assert cfg.dataset.name == "lab_casing"
    assert list(cfg.strategy.names) == ["three_stage"]
    assert cfg.optimizer.name == "cgo"
    assert (cfg.split.train_fraction, cfg.split.n_repeats, cfg.split.sigma_filter) == (0.7, 10, 3.0)
    assert (cfg.budget.pop_size, cfg.budget.iterations) == (30, 100)
    assert cfg.fitness.mode == "train"
    s = _study(cfg)
    assert s.strategies == ("three_stage",) and s.split.n_repeats == 10 and s.budget.iterations == 100
    assert s.optimizer_config.stage_bounds == pytest.approx((1 / 3, 2 / 3))


@pytest.mark.parametrize("schedule,bounds,order", [("thirds", (1 / 3, 2 / 3), (1, 2, 3)),
                                                   ("pct_20_50_30", (0.2, 0.7), (1, 2, 3)),
                                                   ("reversed", (1 / 3, 2 / 3), (3, 2, 1))])
def test_schedule_reaches_the_cgo_config(schedule, bounds, order):
    s = _study(_compose([f"schedule={schedule}"]))
    assert s.optimizer_config.stage_bounds == pytest.approx(bounds)
    assert tuple(s.optimizer_config.stage_order) == order  # chaos=1, gaussian=2, wavelet=3


def test_budget_and_optimizer_groups():
    s = _study(_compose(["budget=evaluations", "optimizer=pso"]))
    assert (s.budget.iterations, s.budget.max_evals, s.optimizer) == (None, 12030, "pso")
    assert _study(_compose(["optimizer=none"])).optimizer is None
    assert _study(_compose(["strategy=all"])).strategies == (
        "original", "chaos", "gaussian", "wavelet", "three_stage")
    assert _study(_compose(["fitness=kfold"])).fitness.mode == "kfold"


@pytest.mark.parametrize("preset,check", [
    ("table1", lambda c: c.hydra.sweeper.params.optimizer == "none,cgo" and list(c.strategy.names) == ["original"]),
    ("fig9", lambda c: c.hydra.sweeper.params.optimizer == "pso,ga,cgo"),
    ("table2", lambda c: len(c.strategy.names) == 5 and c.split.n_repeats == 1),
    ("fig11", lambda c: len(c.strategy.names) == 5 and c.split.n_repeats == 1),
    ("table3", lambda c: len(c.strategy.names) == 5 and c.split.n_repeats == 10),
    ("fig12_13", lambda c: len(c.strategy.names) == 5 and c.split.n_repeats == 10),
    ("table4", lambda c: c.dataset.name == "well_conditions" and len(c.strategy.names) == 5),
    ("table3_instruments", lambda c: c.dataset.kwargs.instrument == "family" and c.worlds == 10
     and len(c.strategy.names) == 5 and c.dataset.seed == 100),
    ("table1_instruments", lambda c: c.dataset.kwargs.instrument == "family" and c.worlds == 10
     and c.hydra.sweeper.params.optimizer == "none,cgo"),
])
def test_presets_compose(preset, check):
    cfg = _compose([f"experiment={preset}"], hydra=True)
    assert cfg.label == preset
    assert check(cfg)


def test_every_preset_file_composes():
    for name in E.group_options("experiment"):
        assert _compose([f"experiment={name}"]).label == name


def test_run_writes_outputs_and_prints_table(small_csv, tmp_path, capsys):
    cfg = _job_cfg(TINY + ["dataset=csv", f"dataset.path={small_csv}", "strategy=all", "split.n_repeats=2",
                           "figures=true"])
    run = run_job(cfg, tmp_path)
    for f in ("config.yaml", "metrics.csv", "convergence.csv", "predictions.csv", "msa.csv", "summary.csv",
              "summary.md", "run.json", "study.png"):
        assert (tmp_path / f).is_file(), f
    m = pd.read_csv(tmp_path / "metrics.csv")
    methods = {"raw", "msa"} | {f"cgo-{s}" for s in ("original", "chaos", "gaussian", "wavelet", "three_stage")}
    assert set(m.method) == methods
    assert set(m.repeat) == {0, 1} and set(m.split) == {"train", "test"}
    assert "Test rows: a random 30 % of the rows per repeat; 2 repeats" in (tmp_path / "summary.md").read_text()
    conv = pd.read_csv(tmp_path / "convergence.csv")
    assert conv.iteration.max() == 3
    # CGO: 8 initial + 4 x 8 per iteration
    assert set(conv[conv.iteration == 3].evals) == {8 + 3 * 32}
    assert run["n_evals"]["cgo-three_stage"] == 8 + 3 * 32
    rec = json.loads((tmp_path / "run.json").read_text())
    assert rec["status"] == "ok" and rec["models"] == ["relm_compensation.json", "msa.json"]
    # the execution plan and where the time went
    import jax

    ex = rec["execution"]
    assert ex["backend"] == jax.default_backend() and ex["kernel"] == "cache_chunked"
    assert ex["devices"] == min(len(jax.devices()), ex["members"]) and ex["members"] == 2 * 5 and ex["processes"] == 1
    assert ex["fitness"] == "icgo.models.relm.train_fitness" and ex["dtype"] == "float32_features" and ex["why"]
    t = rec["timings"]
    for stage in ("prepare", "search", "score", "tables"):
        assert 0 <= t[f"{stage}_compile_s"] <= t[f"{stage}_s"]
    assert t["import_s"] > 0 and t["load_data_s"] > 0 and t["write_s"] > 0
    assert sum(t[f"{s}_s"] for s in ("import", "load_data", "prepare", "search", "score", "tables")) <= rec["total_time_s"]
    # survey QC of the raw stations, recomputed with numpy against the recording's reference field
    from icgo.io.recording import read_recording

    r = read_recording(small_csv)
    keep = pd.read_csv(tmp_path / "predictions.csv").query("method == 'cgo-chaos' and repeat == 0").row.to_numpy()
    B = r.B[keep]
    bad_b = np.abs(np.linalg.norm(B, axis=1) - r.meta["total_field_nT"]) > 300.0
    assert rec["qc"]["raw"]["n"] == len(keep) and rec["qc"]["raw"]["b"] == int(bad_b.sum())
    assert rec["qc"]["msa"]["n"] == len(keep) and "Survey QC" in (tmp_path / "summary.md").read_text()
    out = capsys.readouterr().out
    assert "MAE (deg)" in out and "+/-" in out and "wall time:" in out
    # the summary equals a recomputation from the per-repeat CSV
    s = pd.read_csv(tmp_path / "summary.csv").set_index("method")
    t = m[(m.method == "cgo-chaos") & (m.split == "test")]
    assert s.loc["cgo-chaos", "MAE (deg)"] == f"{t.mae.mean():.4f} +/- {t.mae.std(ddof=1):.4f}"
    # compensation improves on MSA alone on the training rows even with a tiny budget
    tr = m[m.split == "train"].groupby("method").mae.mean()
    assert tr["cgo-three_stage"] < tr["msa"]


@pytest.mark.slow
def test_repeat_zero_of_a_batch_equals_the_single_split(small_csv, tmp_path):
    """experiments.figures takes Table 2 (one split) from repeat 0 of the Table 3 run."""
    base = TINY + ["dataset=csv", f"dataset.path={small_csv}", "strategy=chaos"]
    run_job(_job_cfg(base + ["split.n_repeats=1"]), tmp_path / "one")
    run_job(_job_cfg(base + ["split.n_repeats=3"]), tmp_path / "three")
    a = pd.read_csv(tmp_path / "one" / "metrics.csv")
    b = pd.read_csv(tmp_path / "three" / "metrics.csv")
    b0 = b[b.repeat == 0].reset_index(drop=True)
    np.testing.assert_allclose(a[["mae", "rmse", "r2"]].to_numpy(), b0[["mae", "rmse", "r2"]].to_numpy(),
                               rtol=1e-9, atol=1e-12)


# ---------------------------------------------------------------- bad input
def test_unknown_strategy_is_one_line():
    err = E.check_overrides(["strategy=bogus"])
    assert "unknown strategy 'bogus'" in err and "three_stage" in err and "\n" not in err
    assert "unknown strategy 'nope'" in E.check_overrides(["-m", "strategy=chaos,nope"])
    assert E.check_overrides(["strategy=chaos", "split.n_repeats=3", "+experiment=table3"]) is None


def test_cli_unknown_strategy_fails_in_one_line_from_any_directory(tmp_path):
    p = subprocess.run([sys.executable, "-m", "experiments.run", "strategy=bogus"], cwd=tmp_path,
                       capture_output=True, text=True, env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"},
                       timeout=120)
    assert p.returncode == 2
    lines = p.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: unknown strategy 'bogus'")
    assert not (tmp_path / "outputs").exists()


def _fail_if_called(*a, **k):
    raise AssertionError("computation started before the config was checked")


@pytest.mark.parametrize("override,expect", [
    ("split.n_repeats=-1", "split.n_repeats must be an integer >= 1, got -1"),
    ("split.n_repeats=0", "split.n_repeats must be an integer >= 1"),
    ("model.lam=-1", "model.lam must be a number > 0"),
    ("budget.pop_size=2", "budget.pop_size must be an integer >= 4"),
    ("split.train_fraction=1.5", "split.train_fraction must be in (0, 1)"),
    ("schedule.bounds=[0.7,0.2]", "schedule.bounds must be two fractions"),
    ("dataset=csv", "dataset.path is required"),
    ("dataset=csv dataset.path=/dev/zero", "dataset.path '/dev/zero': not a regular file (a directory, pipe or device)"),
    ("dataset=csv dataset.path=/tmp", "dataset.path '/tmp': not a regular file"),
    ("+dataset.path=/no/such/file.csv", None),
    ("+split.target.seed=3", "split.target is read only by split.protocol=transfer"),
    ("split.protocol=transfer", "split.protocol=transfer needs split.target"),
    ("split.protocol=leave_one_out", "split.protocol must be one of"),
    ("schedule.clock=wall", "schedule.clock must be global or stage, got 'wall'"),
    ("model.tune=true", "model.tune tunes plain RELM only: set optimizer none"),
    ("model.tune=true optimizer=none", "model.tune chooses hidden and lam by validation on the training rows"),
    ("model.tune=true optimizer=none fitness=validation model.hidden=50",
     "model.hidden=50 has no effect with model.tune=true"),
])
def test_bad_settings_fail_in_one_line_before_computation(override, expect, monkeypatch, capsys, tmp_path):
    import icgo.studies.icgo_relm.study
    from icgo.datasets.registry import DATASETS

    monkeypatch.setitem(DATASETS, "lab_casing", _fail_if_called)
    monkeypatch.setattr(icgo.studies.icgo_relm.study, "_run", _fail_if_called)
    overrides = TINY + override.split()
    if override.startswith("+dataset.path"):
        overrides = TINY + ["dataset=csv", "dataset.path=/no/such/file.csv"]
        expect = "dataset.path '/no/such/file.csv': file not found"
    with pytest.raises(SystemExit) as e:
        run_job(_job_cfg(overrides), tmp_path)
    assert e.value.code == E.EXIT_CONFIG
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and expect in err[0]


def test_bad_csv_content_is_one_line(tmp_path, capsys):
    bad = ROOT / "tests" / "data" / "bad_nan.csv"
    with pytest.raises(SystemExit):
        run_job(_job_cfg(TINY + ["dataset=csv", f"dataset.path={bad}", "dataset.require_meta=false"]), tmp_path)
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bad_nan.csv" in err[0]


def test_failed_multirun_job_leaves_marker_and_others_intact(tmp_path, capsys):
    import json

    from omegaconf import open_dict

    from icgo.reporting import records as R

    ok = tmp_path / "0"
    ok.mkdir()
    record = json.dumps({k: None for k in R.RUN_KEYS} | {"status": "ok"})
    (ok / "run.json").write_text(record)
    assert run_job(_job_cfg(TINY + ["split.n_repeats=-3"]), tmp_path / "1", multirun=True) is None
    assert (tmp_path / "1" / FAILED).read_text().startswith("split.n_repeats must be")
    assert (ok / "run.json").read_text() == record
    cfg = _compose([f"hydra.sweep.dir={tmp_path}"], hydra=True)
    with open_dict(cfg):
        cfg.hydra.overrides.task = ["split.n_repeats=2,-3,4"]   # the sweep as typed: jobs 0, 1, 2
    with pytest.raises(SystemExit) as e:
        sweep_report.FailureReport().on_multirun_end(cfg)
    assert e.value.code == 1
    err = capsys.readouterr().err
    assert "3 job(s): 1 ok, 1 failed, 1 not run" in err
    assert "job 1  failed   split.n_repeats=-3  -- split.n_repeats must be" in err
    assert "job 2  not run  split.n_repeats=4" in err


# ----------------------------------------------------------------- progress
def test_progress_comes_between_chunks_with_the_same_result_and_a_cached_program(tmp_path):
    """run_batch(progress=...) reports after each chunk, equals the run without it bitwise, and its compiled
    programs hold no host callback, so a fresh process finds them in the persistent compilation cache."""
    import subprocess
    import sys

    import jax
    import jax.numpy as jnp

    from icgo.optim import run_batch
    from icgo.optim.cgo import CGO

    def sphere(pop, aux):
        return jnp.sum((pop - aux[None]) ** 2, axis=1)

    keys = jax.random.split(jax.random.PRNGKey(0), 3)
    args = (get("cgo"), sphere, (-np.ones(4), np.ones(4)), keys, 6, 20)
    kw = {"configs": CGO.axis_configs(None, ["chaos", "three_stage"]), "aux": jnp.zeros((3, 4))}
    ticks = []
    chunked = run_batch(*args, **kw, progress=lambda d, t: ticks.append((d, t)))
    whole = run_batch(*args, **kw)
    assert ticks == [(d, 20) for d in range(2, 21, 2)]
    for a, b in zip(chunked, whole):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    script = (
        "import sys, jax, jax.numpy as jnp, numpy as np\n"
        "jax.config.update('jax_compilation_cache_dir', sys.argv[1])\n"
        "jax.config.update('jax_persistent_cache_min_compile_time_secs', 0.0)\n"
        "import icgo\nfrom icgo.optim import get, run_batch\n"
        "f = lambda pop, aux: jnp.sum((pop - aux[None]) ** 2, axis=1)\n"
        "run_batch(get('cgo'), f, (-np.ones(4), np.ones(4)), jax.random.split(jax.random.PRNGKey(0), 3), 6, 20,"
        " aux=jnp.zeros((3, 4)), progress=lambda d, t: None)\n")
    subprocess.run([sys.executable, "-c", script, str(tmp_path)], check=True, timeout=300)
    assert any(p.name.startswith("jit__batch_steps_jit") for p in tmp_path.iterdir())


def test_progress_bar_starts_after_the_first_chunk(capsys):
    from icgo.studies.icgo_relm.progress import Progress

    bar = Progress("t")
    assert bar.bar is None and "compiling or loading" in capsys.readouterr().err
    bar(2, 20)
    assert bar.bar.n == 2 and bar.bar.total == 20
    bar(8, 20)
    assert bar.bar.n == 8
    bar.close()


# ------------------------------------------------------------ one source of defaults
def test_composed_default_is_the_study_dataclass_default():
    """`python -m experiments.run` with no override builds icgo.studies.icgo_relm.config.StudyConfig() node by node
    (RunConfig.study_config hands over the same nodes) and the optimizer's default config."""
    import dataclasses

    from icgo.studies.icgo_relm.config import StudyConfig

    cfg = _study(_job_cfg([]))
    default = StudyConfig()
    for f in dataclasses.fields(StudyConfig):
        if f.name == "optimizer_config":
            continue
        assert getattr(cfg, f.name) == getattr(default, f.name), f.name
    assert cfg.precision == "float32_features"
    opt = cfg.optimizer_config
    assert opt == type(opt)(), "the composed optimizer config must equal its dataclass defaults"


def test_no_yaml_of_the_run_door_repeats_a_default():
    """Each default is written once (RunConfig and its nodes, composed first as `config_defaults`): conf/config.yaml
    and the options of the groups RunConfig bases (model, budget, split, fitness) write no key at its default."""
    import yaml

    from icgo.core.settings import defaults_of

    base = defaults_of(RunConfig)
    own = {k: v for k, v in yaml.safe_load((E.CONF_DIR / "config.yaml").read_text()).items()
           if k not in ("defaults", "hydra")}
    assert own == {}, own
    seen = 0
    for group in ("model", "budget", "split", "fitness"):
        for path in sorted((E.CONF_DIR / group).glob("*.yaml")):
            node = yaml.safe_load(path.read_text()) or {}
            same = {k: v for k, v in node.items() if k in base[group] and v == base[group][k]}
            assert not same, f"{path.name} repeats the default(s) {same}"
            seen += 1
    assert seen >= 10
    # the schedule options write only what differs from CGOConfig's own stage defaults (schedule=thirds: nothing)
    from icgo.optim import mutation
    from icgo.optim.cgo import CGOConfig

    cgo = CGOConfig()
    own = {"bounds": list(cgo.stage_bounds), "order": [tuple(mutation.MUTATIONS)[i] for i in cgo.stage_order],
           "clock": "stage" if cgo.wavelet_stage_clock else "global"}
    for path in sorted((E.CONF_DIR / "schedule").glob("*.yaml")):
        node = yaml.safe_load(path.read_text()) or {}
        same = {k: v for k, v in node.items() if v == own[k]}
        assert not same, f"schedule/{path.name} repeats CGOConfig's default(s) {same}"
    assert yaml.safe_load((E.CONF_DIR / "schedule" / "thirds.yaml").read_text()) is None


def test_every_study_field_has_a_config_key():
    """No StudyConfig setting is unreachable from the command line (except those an entry point sets), and each key
    reaches the setting of the same dotted name: a changed key changes exactly that setting."""
    import dataclasses

    from icgo.studies.icgo_relm.config import NODES, StudyConfig

    def get(cfg, key):
        for name in key.split("."):
            cfg = getattr(cfg, name)
        return cfg

    base = _study(_job_cfg([]))
    changed = {"split.n_repeats=3": ("split.n_repeats", 3), "split=leave_azimuth_out": ("split.protocol",
                                                                                        "leave_azimuth_out"),
               "split.seed=4": ("split.seed", 4), "split.sigma_filter=2.5": ("split.sigma_filter", 2.5),
               "split.train_fraction=0.6": ("split.train_fraction", 0.6),
               "msa.model=axial": ("msa.model", "axial"), "msa.reference=known": ("msa.reference", "known"),
               "msa.iterations=7": ("msa.iterations", 7), "model.features=msa": ("model.features", "msa"),
               "model.hidden=12": ("model.hidden", 12), "model.lam=0.5": ("model.lam", 0.5),
               "model.theta_bounds=[-2,2]": ("model.theta_bounds", (-2, 2)),
               "fitness.mode=kfold": ("fitness.mode", "kfold"),
               "fitness.val_fraction=0.2": ("fitness.val_fraction", 0.2), "fitness.k_folds=3": ("fitness.k_folds", 3),
               "optimizer=pso": ("optimizer", "pso"), "strategy=chaos": ("strategies", ("chaos",)),
               "budget.pop_size=12": ("budget.pop_size", 12), "budget=evaluations": ("budget.max_evals", 12030),
               "precision=float64": ("precision", "float64"), "devices=1": ("devices", 1),
               "optimizer=none model.tune=true fitness=validation": ("model.tune", True)}
    for override, (key, value) in changed.items():
        s = _study(_job_cfg(override.split()))
        assert get(s, key) == value and get(base, key) != value, override
    keys = {f.name for f in dataclasses.fields(StudyConfig) if f.name not in NODES}
    keys |= {f"{name}.{f.name}" for name, node in NODES.items() for f in dataclasses.fields(node)}
    missing = keys - {k for k, _ in changed.values()}
    # set by an entry point (repeat_ids, optimizer_config), exclusive with max_evals (iterations), or read by the run
    # door's data loading (split.target: split=transfer)
    assert missing == {"repeat_ids", "optimizer_config", "budget.iterations", "split.target"}
    assert _study(_job_cfg(["budget.iterations=7"])).budget.iterations == 7


@pytest.mark.parametrize("override", ["+split.bogus=1", "+model.hiden=20", "+dataset.pth=x", "+bogus=1",
                                      "+optimizer.lable=x"])
def test_unknown_settings_are_errors(override, capsys, tmp_path):
    with pytest.raises(SystemExit) as e:
        run_job(_job_cfg(TINY + [override]), tmp_path)
    assert e.value.code == E.EXIT_CONFIG
    err = capsys.readouterr().err.strip().splitlines()
    key = override.lstrip("+").split("=")[0]
    assert len(err) == 1 and "unknown setting" in err[0] and key in err[0], err


def test_the_precision_key_and_the_old_dtype_key():
    """precision=float64 reaches StudyConfig.precision; dtype=... is refused in one line naming precision (the run
    door only: another door's config has no such key to replace)."""
    assert _study(_compose(["precision=float64"])).precision == "float64"
    err = E.check_plain_overrides(["dtype=float64"], "config")
    assert err.startswith("setting 'dtype' was replaced: use precision=") and "\n" not in err
    assert E.check_plain_overrides(["dtype=float64"], "misma").startswith("unknown setting 'dtype'")


def test_failed_marker_name_is_the_records_schema_name():
    from icgo.reporting import records

    assert FAILED == records.FAILED_FILE


# ------------------------------------------------------ atomic run directories
def test_a_finished_run_directory_is_refused_then_replaced_whole(small_csv, tmp_path, capsys):
    base = TINY + ["dataset=csv", f"dataset.path={small_csv}", "strategy=chaos", "split.n_repeats=1"]
    run_job(_job_cfg(base + ["figures=true"]), tmp_path)
    first = (tmp_path / "run.json").read_text()
    assert (tmp_path / "study.png").is_file() and not (tmp_path / ".staging").exists()
    capsys.readouterr()
    with pytest.raises(SystemExit) as e:
        run_job(_job_cfg(base), tmp_path)
    assert e.value.code == E.EXIT_CONFIG
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "already holds a complete run" in err[0] and "overwrite=true" in err[0]
    assert (tmp_path / "run.json").read_text() == first
    run_job(_job_cfg(base + ["overwrite=true", "figures=false", "split.seed=3"]), tmp_path)
    assert json.loads((tmp_path / "run.json").read_text())["seed"] == 3
    assert not (tmp_path / "study.png").exists()  # nothing of the old run is left beside the new one
    assert set(pd.read_csv(tmp_path / "metrics.csv").seed) == {3}


def test_a_writer_failing_midway_leaves_the_previous_run_intact(small_csv, tmp_path, monkeypatch, capsys):
    """A full disk (ENOSPC) while the tables are written: the previous complete run is untouched, one line."""
    base = TINY + ["dataset=csv", f"dataset.path={small_csv}", "strategy=chaos", "split.n_repeats=1"]
    run_job(_job_cfg(base), tmp_path)
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()}
    real = pd.DataFrame.to_csv
    calls = {"n": 0}

    def failing(self, path=None, *a, **k):
        calls["n"] += 1
        if calls["n"] == 3:
            raise OSError(28, "No space left on device")
        return real(self, path, *a, **k)

    monkeypatch.setattr(pd.DataFrame, "to_csv", failing)
    capsys.readouterr()
    with pytest.raises(SystemExit):
        run_job(_job_cfg(base + ["overwrite=true", "split.seed=5"]), tmp_path)
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "No space left" in err[0] and "nothing in it was changed" in err[0]
    after = {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()}
    assert after == before and not (tmp_path / ".staging").exists()


def test_rerunning_a_sweep_keeps_finished_jobs(small_csv, tmp_path):
    base = TINY + ["dataset=csv", f"dataset.path={small_csv}", "strategy=chaos", "split.n_repeats=1"]
    first = run_job(_job_cfg(base), tmp_path / "0", multirun=True)
    (tmp_path / "0" / FAILED).write_text("stale\n")
    stamp = (tmp_path / "0" / "run.json").stat().st_mtime_ns
    again = run_job(_job_cfg(base), tmp_path / "0", multirun=True)
    assert again["seed"] == first["seed"] and (tmp_path / "0" / "run.json").stat().st_mtime_ns == stamp
    assert not (tmp_path / "0" / FAILED).exists()


def test_a_sweep_rerun_with_another_config_is_refused_and_changes_nothing(small_csv, tmp_path):
    """A kept job is matched by its config hash, never by its number: another strategy, or more repeats, in the
    job's directory is refused, and the finished run (its .hydra record included) is left byte for byte."""
    from hydra_plugins.icgo_launcher.report import job_status

    base = TINY + ["dataset=csv", f"dataset.path={small_csv}", "split.n_repeats=1"]
    first = run_job(_job_cfg(base + ["strategy=chaos"]), tmp_path / "0", multirun=True)
    assert first["config_sha256"] == cfg_hash(_job_cfg(base + ["strategy=chaos"]))
    before = {p.name: p.read_bytes() for p in (tmp_path / "0").iterdir() if p.is_file()}
    for other in (["strategy=wavelet"], ["strategy=chaos", "split.n_repeats=2"]):
        cfg = _job_cfg(base + other)
        assert run_job(cfg, tmp_path / "0", multirun=True) is None
        assert {p.name: p.read_bytes() for p in (tmp_path / "0").iterdir() if p.is_file()} == before
        status, reason = job_status(tmp_path / "0", OmegaConf.to_container(cfg, resolve=True))
        assert status == "refused" and ("strategy.names" in reason or "split.n_repeats" in reason), reason
    # settings that do not change the result do not make it another run
    assert cfg_hash(_job_cfg(base + ["strategy=chaos", "progress=true", "overwrite=true"])) == first["config_sha256"]
    redo = run_job(_job_cfg(base + ["strategy=wavelet", "overwrite=true"]), tmp_path / "0", multirun=True)
    assert redo["strategies"] == ["wavelet"]


def test_jax_cache_dir_that_cannot_be_created_is_one_line(tmp_path, capsys):
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    with pytest.raises(SystemExit) as e:
        run_job(_job_cfg(["budget=smoke", "progress=false", "figures=false", f"jax_cache_dir={blocker}/cache"]),
                tmp_path / "out")
    err = capsys.readouterr().err.strip().splitlines()
    assert e.value.code == E.EXIT_CONFIG and len(err) == 1 and "jax_cache_dir" in err[0] and "null" in err[0]


def test_the_compilation_cache_is_locked_and_bounded(tmp_path):
    """enable_jax_cache turns on JAX's lock around each cache read and write (a bound on its size does) and the
    program compiled in a fresh process is written under that lock."""
    script = (
        "import sys, jax, jax.numpy as jnp\n"
        "from icgo.core.devices import CACHE_MAX_BYTES, enable_jax_cache\n"
        "enable_jax_cache(sys.argv[1])\n"
        "jax.jit(lambda x: jnp.cumsum(x) * 2)(jnp.ones(5)).block_until_ready()\n"
        "from jax._src import compilation_cache as cc\n"
        "import filelock\n"
        "c = cc._cache\n"
        "assert c.eviction_enabled and c.max_size == CACHE_MAX_BYTES, (c.eviction_enabled, c.max_size)\n"
        "assert isinstance(c.lock, filelock.BaseFileLock) and not isinstance(c.lock, filelock.SoftFileLock)\n")
    subprocess.run([sys.executable, "-c", script, str(tmp_path)], check=True, timeout=300)
    assert (tmp_path / ".lockfile").exists()
    assert [p for p in tmp_path.iterdir() if p.name.endswith("-cache")]


def test_split_options_compose_their_protocol_and_the_transfer_draw_defaults():
    """Each conf/split option sets its protocol; split=transfer's target keeps icgo.studies.common.splits.TransferDraw's
    defaults (it sets none of its own)."""
    from icgo.studies.common.splits import PROTOCOLS

    for option, protocol in (("paper", "random"), ("single", "random"), ("leave_azimuth_out", "leave_azimuth_out"),
                             ("leave_condition_out", "leave_condition_out"), ("transfer", "transfer")):
        assert _study(_job_cfg([f"split={option}"])).split.protocol == protocol
    assert set(PROTOCOLS) == {"random", "leave_azimuth_out", "leave_condition_out", "transfer"}
    target = _run_config(_job_cfg(["split=transfer"])).split.target
    assert target.path is None and target.draw() == {}, "split=transfer keeps every TransferDraw default"


def test_transfer_run_writes_coverage_and_tests_the_target_only(tmp_path):
    run = run_job(_job_cfg(TINY + ["split=transfer", "split.n_repeats=2", "+dataset.kwargs.toolface_step_deg=45.0"]),
                  tmp_path / "t")
    import pandas as pd

    p = pd.read_csv(tmp_path / "t" / "predictions.csv")
    assert set(p[p["split"] == "test"]["survey"]) == {"target"}
    assert set(p[p["survey"] == "target"]["split"]) == {"test"}
    cov = pd.read_csv(tmp_path / "t" / "coverage.csv")
    assert len(cov) == 2 and cov["coverage"].between(0, 1).all()
    assert run["n_repeats"] == 2


@pytest.mark.parametrize("schedule, bounds, clock", [("thirds", (1 / 3, 2 / 3), False),
                                                     ("pct_10_30_60", (0.1, 0.4), False),
                                                     ("own_clock", (1 / 3, 2 / 3), True)])
def test_schedules_reach_the_cgo_config(schedule, bounds, clock):
    oc = _run_config(_job_cfg(TINY + [f"schedule={schedule}"])).optimizer_config()
    assert oc.stage_bounds == pytest.approx(bounds) and oc.wavelet_stage_clock is clock
