"""Gyro inclinometer study (issue #9, patent CN1888384): BP network vs lookup table.

One command writes every table and figure into ``results/gyro_*``::

    .venv/bin/python -m experiments.gyro                       # full study
    .venv/bin/python -m experiments.gyro n_seeds=3 net.epochs=300 sweep.enabled=false relm.enabled=false

Training data: the patent's turntable plan (:func:`icgo.datasets.turntable`:
inclination 3, 5, 10, 15, 25, 35, 45, 55, 65, 75 deg x azimuth and toolface
every 30 deg = 1440 points) from a 2-axis gyro + 2-accelerometer instrument
with repeatable systematic errors. Test data: a dense random set of attitudes
in the same ranges (:func:`icgo.datasets.turntable_random`) and a set half-way
between the grid points in I, A and T (:func:`icgo.datasets.turntable_between`).

Methods, each scored by the azimuth RMSE (deg) on both test sets, ``n_seeds``
seeds per trained method (mean +/- std over seeds, one run):

* ``raw``: the instrument's computed azimuth (patent eq. 7);
* ``table``: the prior-art error table over (I, A), toolface ignored, bilinear;
* the network variants of ``variants`` (:mod:`icgo.nets`; all seeds of one
  variant train in one jitted, vmapped call);
* ``relm`` / ``icgo_relm``: RELM on (I, T, computed A) with random hidden
  weights, or with hidden weights searched by CGO with the three-stage
  4th-seed mutation (the main study's optimizer code, :mod:`icgo.optim`).

Also: error vs number of turntable points (toolface step 30/45/60/90 deg)
for the table and the network, and the ``target=azimuth`` seam at north.
Outputs: ``gyro_methods``, ``gyro_points``, ``gyro_seam`` (.csv + .md),
``gyro_points.png``, ``gyro_seam.png``, ``gyro_toolface.png``, ``gyro_run.json``.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import hydra
import numpy as np
import pandas as pd
from omegaconf import DictConfig, OmegaConf

ROOT = Path(__file__).resolve().parents[1]


class ConfigError(ValueError):
    """A bad setting (one line)."""


# ------------------------------------------------------------------ config
def net_config(cfg: DictConfig, overrides=None):
    """:class:`icgo.nets.NetConfig` from ``cfg.net`` updated by a variant's overrides."""
    from icgo import nets

    d = dict(OmegaConf.to_container(cfg.net, resolve=True))
    d.update(dict(overrides or {}))
    unknown = set(d) - set(nets.NetConfig._fields)
    if unknown:
        raise ConfigError(f"net: unknown key(s) {sorted(unknown)}; known: {list(nets.NetConfig._fields)}")
    d["hidden"] = tuple(int(h) for h in d["hidden"])
    c = nets.NetConfig(**d)
    try:
        return nets._check_config(c)
    except ValueError as e:
        raise ConfigError(str(e)) from None


def check_config(cfg: DictConfig) -> None:
    """Raise :class:`ConfigError` (one line) for a bad setting, before any computation."""
    if int(cfg.n_seeds) < 1:
        raise ConfigError(f"n_seeds must be >= 1, got {cfg.n_seeds}")
    if not cfg.variants:
        raise ConfigError("variants: at least one network variant is needed")
    for name, ov in cfg.variants.items():
        net_config(cfg, ov or {})
    if cfg.sweep.enabled and cfg.sweep.variant not in cfg.variants:
        raise ConfigError(f"sweep.variant {cfg.sweep.variant!r} is not one of variants {list(cfg.variants)}")
    tf = cfg.table.toolface
    if not (tf == "mean" or isinstance(tf, (int, float))):
        raise ConfigError(f"table.toolface must be 'mean' or a toolface in deg, got {tf!r}")
    if cfg.relm.enabled:
        if cfg.relm.encoding not in ("scaled", "sincos"):
            raise ConfigError(f"relm.encoding must be scaled or sincos, got {cfg.relm.encoding!r}")
        if cfg.relm.fitness not in ("train", "validation", "kfold"):
            raise ConfigError(f"relm.fitness must be train, validation or kfold, got {cfg.relm.fitness!r}")
        if not float(cfg.relm.lam) > 0 or int(cfg.relm.hidden) < 1:
            raise ConfigError("relm.lam must be > 0 and relm.hidden >= 1")


# -------------------------------------------------------------------- data
def load_sets(cfg: DictConfig, azimuth_step=None, toolface_step=None):
    """(train, {test name: frame}) from icgo.datasets with the configured plan."""
    from icgo import datasets

    inst = dict(OmegaConf.to_container(cfg.data.instrument, resolve=True) or {})
    inc = [float(x) for x in cfg.data.inclinations_deg]
    a_step = float(cfg.data.azimuth_step_deg if azimuth_step is None else azimuth_step)
    t_step = float(cfg.data.toolface_step_deg if toolface_step is None else toolface_step)
    seed = int(cfg.seed)
    train = datasets.turntable(seed, inclinations_deg=inc, azimuth_step_deg=a_step,
                               toolface_step_deg=t_step, **inst).frame
    if azimuth_step is not None or toolface_step is not None:
        return train, None
    lo, hi = min(inc), max(inc)
    tests = {
        "random": datasets.turntable_random(seed + 1, n=int(cfg.data.n_random),
                                            inclination_range_deg=(lo, hi), **inst).frame,
        "between": datasets.turntable_between(seed + 2, inclinations_deg=inc,
                                              azimuth_step_deg=float(cfg.data.azimuth_step_deg),
                                              toolface_step_deg=float(cfg.data.toolface_step_deg),
                                              **inst).frame,
    }
    return train, tests


def _cols(f: pd.DataFrame):
    """Measured (I, T, A_raw) and reference A (deg) of a turntable frame."""
    return (f["inclination_raw_deg"].to_numpy(), f["toolface_raw_deg"].to_numpy(),
            f["azimuth_raw_deg"].to_numpy(), f["azimuth_deg"].to_numpy())


def azimuth_errors(a_true, a_pred):
    """Wrapped errors ``A_pred - A_true`` (deg), shape of ``a_pred`` ((S, N) or (N,))."""
    from icgo.frames import angle_diff

    return np.asarray(angle_diff(np.asarray(a_pred), np.asarray(a_true)))


def rmse(err, axis=-1):
    """Root mean square over ``axis``."""
    return np.sqrt(np.mean(np.asarray(err) ** 2, axis=axis))


# ----------------------------------------------------------------- methods
def table_predict(cfg: DictConfig, train: pd.DataFrame, tests: dict):
    """Lookup table from the turntable points; {test: (N,) compensated azimuth}."""
    from icgo import nets

    err = azimuth_errors(train["azimuth_raw_deg"], train["azimuth_deg"])  # A_true - A_raw
    tf = cfg.table.toolface
    table = nets.lookup_table_fit(
        train["inclination_deg"], train["azimuth_deg"], err, toolface_deg=train["toolface_deg"],
        at_toolface_deg=None if tf == "mean" else float(tf))
    return {k: np.asarray(nets.lookup_table_predict(table, f["inclination_raw_deg"], f["azimuth_raw_deg"]))
            for k, f in tests.items()}


def net_predict(ncfg, keys, train: pd.DataFrame, tests: dict):
    """Train ``len(keys)`` networks in one vmapped call; ({test: (S, N)}, TrainResult, seconds)."""
    import jax

    from icgo import nets

    i, t, a, at = _cols(train)
    t0 = time.perf_counter()
    res = nets.fit(keys, i, t, a, at, ncfg)
    jax.block_until_ready(res.params)
    secs = time.perf_counter() - t0
    preds = {}
    for k, f in tests.items():
        fi, ft, fa, _ = _cols(f)
        preds[k] = np.asarray(nets.predict(res, fi, ft, fa, ncfg))
    return preds, res, secs


def relm_predict(cfg: DictConfig, keys, train: pd.DataFrame, tests: dict, optimized: bool):
    """Plain RELM (random hidden weights) or ICGO-RELM on inputs (I, T, computed A).

    The hidden weights theta of each seed are drawn from U(theta_bounds) or
    searched by ``relm.optimizer`` (CGO, strategy ``relm.strategy``) on the
    training-only RELM fitness of :mod:`icgo.relm` (all seeds in one
    ``run_batch`` call); the output weights are the ridge solution on all
    training points. Target: the wrapped error ``A_true - A_raw``.

    Returns:
        ({test: (S, N) compensated azimuth}, seconds, best fitness (S,)).
    """
    import jax
    import jax.numpy as jnp

    from icgo import nets, relm
    from icgo.frames import wrap360

    rc = cfg.relm
    L, lam = int(rc.hidden), float(rc.lam)
    i, t, a, at = _cols(train)
    X = jnp.asarray(nets.encode_inputs(i, t, a, rc.encoding))
    T = jnp.asarray(azimuth_errors(a, at))
    n_in = X.shape[1]
    S = keys.shape[0]
    w = jnp.ones(X.shape[0])
    lo, hi = (float(x) for x in rc.theta_bounds)
    t0 = time.perf_counter()
    k_theta, k_fold = jax.vmap(lambda k: jax.random.split(k, 2))(keys).transpose(1, 0, 2)
    mean, std = relm.standardize_stats(X, w)
    Xs = relm.standardize(X, mean, std)
    fw, sw = jax.vmap(lambda k: relm.fold_weights(k, w, rc.fitness))(k_fold)
    data = relm.FitData(jnp.broadcast_to(Xs, (S,) + Xs.shape), jnp.broadcast_to(T, (S,) + T.shape), fw, sw)
    if optimized:
        from icgo.optim import run_batch

        D = relm.n_params(L, n_in)
        res = run_batch(rc.optimizer, relm.make_fitness(lam, L), (np.full(D, lo), np.full(D, hi)), keys,
                        int(rc.pop_size), int(rc.iterations),
                        strategies=[rc.strategy] if rc.optimizer == "cgo" else None, aux=data)
        theta = res.best_x[0] if rc.optimizer == "cgo" else res.best_x
        best_f = res.best_f[0] if rc.optimizer == "cgo" else res.best_f
    else:
        theta = jax.vmap(lambda k: relm.random_theta(k, L, (), lo, hi, n_inputs=n_in))(k_theta)
        best_f = jax.vmap(lambda th, d: relm.fitness(th[None], d, lam, L)[0])(theta, data)
    models = jax.vmap(lambda th: relm.fit_unchecked(th, X, T, lam, w, L))(theta)
    jax.block_until_ready(models.beta)
    secs = time.perf_counter() - t0
    preds = {}
    for k, f in tests.items():
        fi, ft, fa, _ = _cols(f)
        Xt = jnp.asarray(nets.encode_inputs(fi, ft, fa, rc.encoding))
        e = jax.vmap(lambda m: relm.predict(m, Xt))(models)
        preds[k] = np.asarray(wrap360(jnp.asarray(fa)[None] + e))
    return preds, secs, np.asarray(best_f)


# ----------------------------------------------------------------- tables
def _pm(x, digits=3):
    x = np.atleast_1d(np.asarray(x, float))
    return f"{x.mean():.{digits}f} +/- {x.std():.{digits}f}" if x.size > 1 else f"{x[0]:.{digits}f}"


def score_rows(method, preds: dict, tests: dict, extra=None):
    """One row per test set: RMSE / MAE / max |error| per seed, summarised."""
    rows = []
    for k, f in tests.items():
        e = np.atleast_2d(azimuth_errors(f["azimuth_deg"].to_numpy(), preds[k]))
        r = rmse(e)
        rows.append({"method": method, "test": k, "n_seeds": e.shape[0],
                     "rmse_mean": r.mean(), "rmse_std": r.std(),
                     "mae_mean": np.abs(e).mean(1).mean(), "max_abs_mean": np.abs(e).max(1).mean(),
                     "rmse": _pm(r), **(extra or {})})
    return rows


def write_table(df: pd.DataFrame, path: Path, title: str, note: str = "") -> None:
    """CSV + Markdown (with a title and a note)."""
    df.to_csv(path.with_suffix(".csv"), index=False)
    md = f"# {title}\n\n{note}\n\n" + df.to_markdown(index=False, floatfmt=".4f") + "\n"
    path.with_suffix(".md").write_text(md)


def seam_rows(method, preds, f: pd.DataFrame, band):
    """RMSE within ``band`` deg of north vs elsewhere (random test set)."""
    from icgo.frames import angle_diff

    a = f["azimuth_deg"].to_numpy()
    north = np.abs(np.asarray(angle_diff(a, 0.0))) < band
    e = np.atleast_2d(azimuth_errors(a, preds))
    rn, rf = rmse(e[:, north]), rmse(e[:, ~north])
    return {"method": method, "n_north": int(north.sum()), "rmse_north_mean": rn.mean(),
            "rmse_north_std": rn.std(), "rmse_elsewhere_mean": rf.mean(), "rmse_elsewhere_std": rf.std(),
            "ratio": rn.mean() / rf.mean()}


# ----------------------------------------------------------------- figures
def fig_seam(preds: dict, f: pd.DataFrame, band, path: Path) -> None:
    """|error| vs true azimuth (10-deg bins, RMS over points and seeds) per method."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    a = np.mod(f["azimuth_deg"].to_numpy(), 360.0)
    edges = np.arange(0, 361, 10.0)
    centers = 0.5 * (edges[1:] + edges[:-1])
    fig, ax = plt.subplots(figsize=(8, 4.2))
    for name, p in preds.items():
        e = np.atleast_2d(azimuth_errors(a, p))
        b = np.digitize(a, edges) - 1
        y = [rmse(e[:, b == j].ravel(), 0) if np.any(b == j) else np.nan for j in range(len(centers))]
        ax.plot(centers, y, marker="o", ms=3, label=name)
    ax.axvspan(0, band, color="0.9")
    ax.axvspan(360 - band, 360, color="0.9")
    ax.set_yscale("log")
    ax.set_xlabel("true azimuth (deg)")
    ax.set_ylabel("azimuth RMSE in 10-deg bin (deg)")
    ax.set_xticks(np.arange(0, 361, 45))
    ax.set_title("target=azimuth fails at the 0/360 seam; target=error does not (random test set)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def fig_points(df: pd.DataFrame, path: Path) -> None:
    """Test RMSE vs number of turntable points, table vs network, one panel per test set."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tests = list(dict.fromkeys(df["test"]))
    fig, axes = plt.subplots(1, len(tests), figsize=(5 * len(tests), 4), squeeze=False)
    for ax, k in zip(axes[0], tests):
        d = df[df["test"] == k]
        for m, mk in (("table", "s"), ("network", "o"), ("raw", "")):
            dm = d[d["method"] == m].sort_values("n_points")
            if dm.empty:
                continue
            if m == "raw":
                ax.axhline(dm["rmse_mean"].iloc[0], color="0.5", ls="--", label="raw")
                continue
            for a_step, g in dm.groupby("azimuth_step_deg"):
                ax.errorbar(g["n_points"], g["rmse_mean"], yerr=g["rmse_std"], marker=mk, capsize=3,
                            label=f"{m}, azimuth step {a_step:g}")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ticks = sorted(set(d["n_points"].dropna().astype(int)))
        ax.set_xticks(ticks, [str(t) for t in ticks], rotation=60, fontsize=7)
        ax.minorticks_off()
        yt = [0.1, 0.2, 0.3, 0.5, 1.0, 2.0, 3.0, 5.0, 10.0]
        ax.set_yticks(yt, [f"{y:g}" for y in yt])
        ax.set_xlabel("turntable points")
        ax.set_ylabel("azimuth RMSE (deg)")
        ax.set_title(f"test set: {k}")
        ax.legend(fontsize=7, loc="center right")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def fig_toolface(train: pd.DataFrame, path: Path, inclination=25.0) -> None:
    """Raw azimuth error vs toolface at one inclination, one curve per azimuth (why the table fails)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    d = train[np.isclose(train["inclination_deg"], inclination)]
    fig, ax = plt.subplots(figsize=(7, 4))
    for a, g in d.groupby("azimuth_deg"):
        g = g.sort_values("toolface_deg")
        ax.plot(g["toolface_deg"], azimuth_errors(g["azimuth_deg"], g["azimuth_raw_deg"]), marker=".",
                lw=0.8, label=f"A={a:g}")
    ax.set_xlabel("toolface (deg)")
    ax.set_ylabel("raw azimuth error (deg)")
    ax.set_title(f"raw error vs toolface at I={inclination:g} deg: the table's toolface blind spot")
    ax.legend(fontsize=6, ncol=3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


# -------------------------------------------------------------------- study
def run(cfg: DictConfig) -> dict:
    """The whole study; writes ``results/gyro_*`` and returns a summary dict."""
    check_config(cfg)
    import jax

    import icgo  # noqa: F401  (float64)

    if cfg.get("jax_cache"):
        p = Path(str(cfg.jax_cache))
        p = p if p.is_absolute() else ROOT / p
        jax.config.update("jax_compilation_cache_dir", str(p))
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    out = Path(str(cfg.out_dir))
    out = out if out.is_absolute() else ROOT / out
    out.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    keys = jax.random.split(jax.random.PRNGKey(int(cfg.seed)), int(cfg.n_seeds))
    train, tests = load_sets(cfg)
    print(f"[gyro] train {len(train)} turntable points; tests " +
          ", ".join(f"{k} {len(v)}" for k, v in tests.items()), flush=True)
    summary = {"n_train": len(train), "n_tests": {k: len(v) for k, v in tests.items()},
               "train_seconds": {}, "best_epoch": {}}

    # --- methods table
    rows = score_rows("raw", {k: f["azimuth_raw_deg"].to_numpy() for k, f in tests.items()}, tests)
    rows += score_rows("table", table_predict(cfg, train, tests), tests)
    seam_preds, seam = {}, []
    band = float(cfg.seam.band_deg)
    net_preds = {}
    for name, ov in cfg.variants.items():
        ncfg = net_config(cfg, ov or {})
        preds, res, secs = net_predict(ncfg, keys, train, tests)
        net_preds[name] = preds
        summary["train_seconds"][name] = secs
        summary["best_epoch"][name] = np.asarray(res.best_epoch).tolist()
        rows += score_rows(name, preds, tests, {"train_s": secs})
        print(f"[gyro] {name}: {secs:.1f} s for {len(keys)} networks; random RMSE "
              f"{_pm(rmse(azimuth_errors(tests['random']['azimuth_deg'].to_numpy(), preds['random'])))}",
              flush=True)
    if cfg.relm.enabled:
        for name, opt in (("relm", False), ("icgo_relm", True)):
            preds, secs, best_f = relm_predict(cfg, keys, train, tests, opt)
            net_preds[name] = preds
            summary["train_seconds"][name] = secs
            summary[f"{name}_train_fitness"] = best_f.tolist()
            rows += score_rows(name, preds, tests, {"train_s": secs})
            print(f"[gyro] {name}: {secs:.1f} s", flush=True)
    methods = pd.DataFrame(rows)
    write_table(methods[["method", "test", "n_seeds", "rmse", "rmse_mean", "rmse_std", "mae_mean",
                         "max_abs_mean"] + (["train_s"] if "train_s" in methods else [])],
                out / "gyro_methods",
                "Gyro inclinometer: azimuth RMSE (deg) on attitudes off the training grid",
                f"Trained on the patent's turntable plan ({len(train)} points); {int(cfg.n_seeds)} seeds "
                "per trained method (mean +/- std over seeds, one run). `train_s`: wall time of one "
                "vmapped call for all seeds, including compilation. Command: `python -m experiments.gyro`.")

    # --- seam
    rand = tests["random"]
    seam.append(seam_rows("raw", rand["azimuth_raw_deg"].to_numpy(), rand, band))
    for name, p in net_preds.items():
        seam.append(seam_rows(name, p["random"], rand, band))
        if name in ("net_azimuth", "net_error", "net_azimuth_sgd_patent", "net_error_sgd_patent"):
            seam_preds[name] = p["random"]
    seam_preds["raw"] = rand["azimuth_raw_deg"].to_numpy()
    write_table(pd.DataFrame(seam), out / "gyro_seam", "The 0/360 seam: RMSE near north vs elsewhere",
                f"Random test set; 'north' = |true azimuth| < {band:g} deg. ratio = north / elsewhere.")
    fig_seam(seam_preds, rand, band, out / "gyro_seam.png")
    fig_toolface(train, out / "gyro_toolface.png")

    # --- points sweep
    if cfg.sweep.enabled:
        prow = []
        raw_rows = score_rows("raw", {k: f["azimuth_raw_deg"].to_numpy() for k, f in tests.items()}, tests)
        for r in raw_rows:
            prow.append({**r, "azimuth_step_deg": np.nan, "toolface_step_deg": np.nan, "n_points": np.nan})
        ncfg = net_config(cfg, cfg.variants[cfg.sweep.variant] or {})
        steps = [(float(a), float(t), True) for a in cfg.sweep.azimuth_steps for t in cfg.sweep.toolface_steps]
        steps += [(float(a), float(t), False) for a in cfg.sweep.table_only_azimuth_steps
                  for t in cfg.sweep.toolface_steps]
        for a_step, t_step, with_net in steps:
            tr, _ = load_sets(cfg, a_step, t_step)
            meta = {"azimuth_step_deg": a_step, "toolface_step_deg": t_step, "n_points": len(tr)}
            prow += score_rows("table", table_predict(cfg, tr, tests), tests, meta)
            if with_net:
                if (a_step, t_step) == (float(cfg.data.azimuth_step_deg), float(cfg.data.toolface_step_deg)):
                    preds = net_preds[cfg.sweep.variant]
                else:
                    preds, _, secs = net_predict(ncfg, keys, tr, tests)
                prow += score_rows("network", preds, tests, meta)
            print(f"[gyro] sweep A step {a_step:g}, T step {t_step:g}: {len(tr)} points", flush=True)
        pts = pd.DataFrame(prow)
        write_table(pts[["method", "test", "azimuth_step_deg", "toolface_step_deg", "n_points", "rmse",
                         "rmse_mean", "rmse_std"]], out / "gyro_points",
                    "Azimuth RMSE (deg) vs number of turntable points",
                    f"network = variant `{cfg.sweep.variant}`, {int(cfg.n_seeds)} seeds (mean +/- std); "
                    "inclinations as the patent; test sets fixed (30-deg plan's between-grid set).")
        fig_points(pts, out / "gyro_points.png")

    summary["total_seconds"] = time.perf_counter() - t_start
    summary["config"] = OmegaConf.to_container(cfg, resolve=True)
    (out / "gyro_run.json").write_text(json.dumps(summary, indent=1, default=float))
    print(f"[gyro] done in {summary['total_seconds']:.0f} s; results in {out}", flush=True)
    return summary


@hydra.main(config_path="../conf", config_name="gyro", version_base="1.3")
def main(cfg: DictConfig) -> None:
    try:
        run(cfg)
    except ConfigError as e:
        raise SystemExit(f"error: {e}") from None


if __name__ == "__main__":
    main()
