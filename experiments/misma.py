"""MISMA study (issue #8): MISMA vs SMA on ``rotating_drill`` and the 9 real devices.

One command writes every table and figure into ``results/misma_*``::

    .venv/bin/python -m experiments.misma                    # full study
    .venv/bin/python -m experiments.misma simulated.repeats=3 simulated.n_iter=300 real.enabled=false

Simulated part (per rotating_drill variant): MISMA and SMA, population 30,
12 parameters, ``repeats`` vmapped repeats each; convergence curves,
iterations to reach ``threshold_factor * F(true)``, recovered vs true
parameters, |B| before/after, absolute azimuth error at the static survey
points (raw, SMA, MISMA, plus the deterministic baselines).

Real part: each circuitpython-mag-cal device calibrated by the ellipsoid fit,
the 12-parameter fit (+ axis alignment), MISMA (+ axis alignment) and the
group-aware joint fit; scored by the peer package's own metric in-sample and
held out (fit without one rolled group, score on it), with the peer's
``fit_ellipsoid`` / ``fit_to_axis`` / ``fit_non_linear`` run side by side.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import hydra
import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
from omegaconf import DictConfig, OmegaConf

import icgo  # noqa: F401  (float64)
from icgo import calibration as cal
from icgo import datasets
from icgo.io import MAG_CAL_DEVICE_TO_TOOL, load_mag_cal_device, mag_cal_devices
from icgo.optim import base
from icgo.optim import misma as misma_mod  # noqa: F401  (registers "misma")
from icgo.optim.sma import SMAConfig

ROOT = Path(__file__).resolve().parents[1]


# ---------------------------------------------------------------- simulated
def _prior_box(ref_nT, matrix_halfwidth, bias_halfwidth):
    """SMA's prior-knowledge bounds: R^-1 = I +/- h, b = 0 +/- h_b |M_omega|."""
    c = np.concatenate([np.eye(3).ravel(), np.zeros(3)])
    h = np.concatenate([np.full(9, matrix_halfwidth), np.full(3, bias_halfwidth * ref_nT)])
    return c - h, c + h


def _iters_to(curve, threshold):
    """First iteration (1-based) with best <= threshold, NaN if never; curve (R, T)."""
    hit = np.asarray(curve) <= threshold
    return np.where(hit.any(1), hit.argmax(1) + 1.0, np.nan)


def simulated_variant(name, overrides, scfg, seed, out: Path) -> dict:
    """Run MISMA and SMA on one rotating_drill variant; write its tables/figures; return a summary."""
    ds = datasets.rotating_drill(seed, **dict(overrides))
    fr, meta, truth = ds.frame, ds.meta, ds.truth
    G, B = fr[["gx", "gy", "gz"]].to_numpy(float), fr[["bx", "by", "bz"]].to_numpy(float)
    static = fr["static"].to_numpy().astype(bool)
    t = fr["time_s"].to_numpy(float)
    seg = (t // float(truth["stop_every_s"])).astype(np.int32)
    ref = float(meta["total_field_nT"])  # |M_omega|: the modulus of the gyro-rotated reference field (docs/misma.md)
    k = int(scfg.subsample)
    sel = static | (np.arange(len(t)) % k == 0)
    dotw = static[sel].astype(float) if scfg.dot_samples == "static" else None
    data = cal.make_caldata(G[sel], B[sel], ref, seg[sel], ~static[sel], dot_weights=dotw)
    ob = scfg.objective
    obj = cal.MismaObjective(data, ob.pearson_threshold, ob.pearson_mode, ob.mu_magnitude, ob.mu_pearson)
    x_true = np.asarray(cal.params_from_error_model(np.asarray(truth["R"]), np.asarray(truth["b_nT"])))
    f_true = float(obj(x_true[None])[0])

    U = cal.modulus_fit(B[sel], ref)
    mc = scfg.misma
    lb_m, ub_m = misma_mod.misma_bounds(U, ref, mc.matrix_halfwidth, mc.bias_halfwidth)
    lb_s, ub_s = _prior_box(ref, scfg.sma.matrix_halfwidth, scfg.sma.bias_halfwidth)
    cfg_m = misma_mod.MISMAConfig(mc.z_max, mc.d, mc.gmr_threshold, mc.p_mode)
    cfg_s = SMAConfig(z=scfg.sma.z)
    k_m, k_s = jax.random.split(jax.random.PRNGKey(seed + 1))
    R, T, P = int(scfg.repeats), int(scfg.n_iter), int(scfg.pop_size)
    t0 = time.time()
    res_m = base.run_batch("misma", obj, (lb_m, ub_m), jax.random.split(k_m, R), P, T, config=cfg_m)
    jax.block_until_ready(res_m.best_f)
    t_m = time.time() - t0
    t0 = time.time()
    res_s = base.run_batch("sma", obj, (lb_s, ub_s), jax.random.split(k_s, R), P, T, config=cfg_s)
    jax.block_until_ready(res_s.best_f)
    t_s = time.time() - t0

    # azimuth error at the static survey points (reference: true magnetic azimuth)
    az_ref = fr["azimuth_deg"].to_numpy(float)[static]
    Gs, Bs = G[static], B[static]

    def az_err(x):
        return float(np.mean(np.abs(cal.azimuth_error_deg(Gs, np.asarray(cal.correct(jnp.asarray(x), Bs)), az_ref))))

    raw = float(np.mean(np.abs(cal.azimuth_error_deg(Gs, Bs, az_ref))))
    az_m = np.array([az_err(x) for x in np.asarray(res_m.best_x)])
    az_s = np.array([az_err(x) for x in np.asarray(res_s.best_x)])
    baselines = {"true parameters": az_err(x_true), "U (modulus fit, MISMA's centre)": az_err(U)}
    try:
        baselines["12-parameter least squares"] = az_err(cal.fit_twelve(G[sel], B[sel], ref, x0=U))
    except ValueError as e:
        baselines["12-parameter least squares"] = float("nan")
        print(f"[{name}] 12-parameter least squares: {e}")

    thr = scfg.threshold_factor * f_true
    it_m, it_s = _iters_to(res_m.curve, thr), _iters_to(res_s.curve, thr)
    med_m = float(np.nanmedian(it_m)) if np.isfinite(it_m).any() else float("nan")
    med_s = float(np.nanmedian(it_s)) if np.isfinite(it_s).any() else float("nan")
    speedup = 100.0 * (1.0 - med_m / med_s) if np.isfinite(med_m) and np.isfinite(med_s) else float("nan")

    # recovered parameters: the median-fitness repeat of each algorithm
    im = int(np.argsort(np.asarray(res_m.best_f))[R // 2])
    is_ = int(np.argsort(np.asarray(res_s.best_f))[R // 2])
    names = [f"Rinv_{i}{j}" for i in range(1, 4) for j in range(1, 4)] + ["b_x_nT", "b_y_nT", "b_z_nT"]
    xm_, xs_ = np.asarray(res_m.best_x[im]), np.asarray(res_s.best_x[is_])
    tol = np.r_[np.full(9, scfg.tolerance.matrix), np.full(3, scfg.tolerance.bias_nT)]
    params = pd.DataFrame({"parameter": names, "true": x_true, "MISMA": xm_, "SMA": xs_,
                           "MISMA_abs_err": np.abs(xm_ - x_true), "SMA_abs_err": np.abs(xs_ - x_true),
                           "tolerance": tol, "MISMA_within": np.abs(xm_ - x_true) <= tol})
    # identifiability: singular values of the fitness Jacobian (dot + magnitude residuals) at the truth
    sv = _identifiability(G[sel], B[sel], ref, x_true)

    def mod(x):
        return np.linalg.norm(np.asarray(cal.correct(jnp.asarray(x), B)), axis=1)

    Bm = {"raw": np.linalg.norm(B, axis=1), "SMA": mod(xs_), "MISMA": mod(xm_)}
    mags = pd.DataFrame({k2: {"mean_nT": v.mean(), "std_nT": v.std(), "mean_abs_dev_from_ref_nT": np.abs(v - ref).mean()}
                         for k2, v in Bm.items()}).T
    summary = {
        "variant": name, "overrides": dict(overrides), "n_samples_fitness": int(sel.sum()),
        "F_true": f_true, "threshold": thr,
        "MISMA_best_f_median": float(np.median(res_m.best_f)), "SMA_best_f_median": float(np.median(res_s.best_f)),
        "MISMA_iters_to_threshold_median": med_m, "SMA_iters_to_threshold_median": med_s,
        "MISMA_reached": int(np.isfinite(it_m).sum()), "SMA_reached": int(np.isfinite(it_s).sum()),
        "speedup_pct": speedup,
        "az_err_raw_deg": raw, "az_err_SMA_deg_mean": float(az_s.mean()), "az_err_MISMA_deg_mean": float(az_m.mean()),
        "az_err_MISMA_deg_max": float(az_m.max()), "az_reduction_MISMA_pct": 100 * (1 - az_m.mean() / raw),
        "az_reduction_SMA_pct": 100 * (1 - az_s.mean() / raw), "baselines_az_err_deg": baselines,
        "params_within_tolerance_MISMA": int(params["MISMA_within"].sum()),
        "repeats_all_params_within_tolerance_MISMA": int(np.all(np.abs(np.asarray(res_m.best_x) - x_true) <= tol, 1).sum()),
        "repeats_all_params_within_tolerance_SMA": int(np.all(np.abs(np.asarray(res_s.best_x) - x_true) <= tol, 1).sum()),
        "jacobian_singular_values": sv.tolist(), "runtime_s": {"MISMA": t_m, "SMA": t_s},
    }
    params.to_csv(out / f"misma_params_{name}.csv", index=False)
    (out / f"misma_params_{name}.md").write_text(params.to_markdown(index=False, floatfmt=".5g") + "\n")
    mags.to_csv(out / f"misma_modulus_{name}.csv")
    _plots(name, res_m, res_s, thr, Bm, ref, t, static, Gs, Bs, az_ref, xm_, xs_, out)
    return summary


def _identifiability(G, B, ref, x):
    """Singular values (descending, relative to the largest) of d(residuals)/d(scaled params) at x."""
    scale = np.r_[np.full(9, 1.0), np.full(3, ref)]
    Gj, Bj = jnp.asarray(G), jnp.asarray(B)

    def res(u):
        Bc = cal.correct(u * scale, Bj)
        d = cal.normalized_dot(Gj, Bc)
        return jnp.concatenate([d - jnp.mean(d), jnp.linalg.norm(Bc, axis=1) / ref - 1.0])

    s = np.linalg.svd(np.asarray(jax.jacfwd(res)(jnp.asarray(x / scale))), compute_uv=False)
    return s / s[0]


def _plots(name, res_m, res_s, thr, Bm, ref, t, static, Gs, Bs, az_ref, xm_, xs_, out):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 3, figsize=(15, 4))
    it = np.arange(1, res_m.curve.shape[1] + 1)
    for res, lab, c in ((res_m, "MISMA", "C0"), (res_s, "SMA", "C3")):
        cu = np.asarray(res.curve)
        ax[0].plot(it, np.median(cu, 0), c, label=f"{lab} (median of {cu.shape[0]})")
        ax[0].fill_between(it, np.quantile(cu, 0.25, 0), np.quantile(cu, 0.75, 0), color=c, alpha=0.25)
    ax[0].axhline(thr, color="k", ls=":", label="threshold")
    ax[0].set(yscale="log", xlabel="iteration", ylabel="best fitness", title=f"convergence ({name})")
    ax[0].legend()
    for k2, v in Bm.items():
        ax[1].plot(t, v / 1000.0, lw=0.6, label=k2)
    ax[1].axhline(ref / 1000.0, color="k", ls=":", label="|M_omega|")
    ax[1].set(xlabel="time (s)", ylabel="|B| (uT)", title="field modulus before/after")
    ax[1].legend()
    surveys = np.arange(len(az_ref))
    e_raw = np.abs(cal.azimuth_error_deg(Gs, Bs, az_ref))
    e_m = np.abs(cal.azimuth_error_deg(Gs, np.asarray(cal.correct(jnp.asarray(xm_), Bs)), az_ref))
    e_s = np.abs(cal.azimuth_error_deg(Gs, np.asarray(cal.correct(jnp.asarray(xs_), Bs)), az_ref))
    for e, lab in ((e_raw, "before"), (e_s, "SMA"), (e_m, "MISMA")):
        ax[2].plot(surveys, e, ".", ms=3, label=f"{lab} (mean {e.mean():.2f} deg)")
    ax[2].set(yscale="log", xlabel="static sample index", ylabel="|azimuth error| (deg)", title="static survey points")
    ax[2].legend()
    fig.tight_layout()
    fig.savefig(out / f"misma_{name}.png", dpi=110)
    plt.close(fig)


# ---------------------------------------------------------------- real data
def _device_frame(G, B):
    """Tool frame -> mag_cal device frame (inverse of icgo.io's permutation); mag in uT."""
    perm = list(MAG_CAL_DEVICE_TO_TOOL)
    gd, md = np.empty_like(G), np.empty_like(B)
    gd[:, perm], md[:, perm] = G, B / 1000.0
    return gd, md


def _peer(G, B, train, rolled_train, score_groups):
    """Peer pipeline fitted on ``train`` rows; returns accuracy on score groups after each stage."""
    from mag_cal import Calibration

    gd, md = _device_frame(G, B)
    fit_pairs = [(md[m], gd[m]) for m in rolled_train]
    score_pairs = [(md[m], gd[m]) for m in score_groups]
    c = Calibration()
    c.fit_ellipsoid(md[train], gd[train])
    out = {"peer_ellipsoid": c.accuracy(score_pairs)}
    c.fit_to_axis(fit_pairs)
    out["peer_fit_to_axis"] = c.accuracy(score_pairs)
    c.fit_non_linear(fit_pairs)
    out["peer_fit_non_linear"] = c.accuracy(score_pairs)
    return out


_OBJ = {}


def _objective(n):
    """One MismaObjective per recording size (data passed as aux, so it compiles once per size)."""
    if n not in _OBJ:
        _OBJ[n] = cal.MismaObjective(cal.make_caldata(np.ones((n, 3)), np.ones((n, 3)), 1.0))
    return _OBJ[n]


def _ours(G, B, groups, train, score_mask, rcfg, key):
    """Our four pipelines fitted on ``train`` rows, scored (peer metric) on ``score_mask`` rows."""
    Gt, Bt, gt = G[train], B[train], groups[train]
    xg = cal.ellipsoid_fit_accel(Gt)
    xm = cal.ellipsoid_fit(Bt, 1.0, Gt)
    Gc = lambda x: np.asarray(cal.correct(jnp.asarray(x), G))  # noqa: E731
    Bc = lambda x: np.asarray(cal.correct(jnp.asarray(x), B))  # noqa: E731
    score = lambda g_, b_: cal.group_spread_deg(g_[score_mask], b_[score_mask], groups[score_mask])[0]  # noqa: E731
    out = {"ellipsoid": score(Gc(xg), Bc(xm))}
    Gt_c = np.asarray(cal.correct(jnp.asarray(xg), Gt))
    x12 = cal.fit_twelve(Gt_c, Bt, 1.0, x0=xm)
    Q = cal.align_to_axis(Gt_c, np.asarray(cal.correct(jnp.asarray(x12), Bt)), gt)
    out["twelve+axis"] = score(Gc(xg) @ Q.T, Bc(x12) @ Q.T)
    R = int(rcfg.misma_repeats)
    data = cal.make_caldata(Gt_c, Bt, 1.0)
    aux = jax.tree_util.tree_map(lambda a: jnp.broadcast_to(a, (R,) + jnp.shape(a)), data)
    lb, ub = misma_mod.misma_bounds(xm, 1.0)
    r = base.run_batch("misma", _objective(len(Bt)), (lb, ub), jax.random.split(key, R), 30, int(rcfg.misma_iter),
                       aux=aux)
    xmi = np.asarray(r.best_x[int(np.argmin(np.asarray(r.best_f)))])
    Q = cal.align_to_axis(Gt_c, np.asarray(cal.correct(jnp.asarray(xmi), Bt)), gt)
    out["misma+axis"] = score(Gc(xg) @ Q.T, Bc(xmi) @ Q.T)
    jg, jm = cal.fit_joint(Gt, Bt, gt, xg, xm)
    out["joint"] = score(Gc(jg), Bc(jm))
    return out


def real_study(rcfg, seed, out: Path) -> pd.DataFrame:
    """All 9 devices: in-sample and held-out spread, ours and the peer's, one row per device and split."""
    rows = []
    key = jax.random.PRNGKey(seed + 7)
    for name in mag_cal_devices():
        rec = load_mag_cal_device(name)
        G, B, groups = rec.G, rec.B, rec.frame["group"].to_numpy()
        rolled = [groups == g for g in (8, 9)]
        allrows = np.ones(len(G), bool)
        splits = [("in-sample", allrows, rolled, allrows)]
        for h, g in enumerate((8, 9)):
            splits.append((f"held-out group {g}", groups != g, [rolled[1 - h]], groups == g))
        for split, train, rolled_train, score_mask in splits:
            key, sub = jax.random.split(key)
            row = {"device": name, "split": split, **_ours(G, B, groups, train, score_mask, rcfg, sub)}
            if rcfg.peer:
                score_groups = [m for m in rolled if (m & score_mask).any()]
                row.update(_peer(G, B, train, rolled_train, score_groups))
            rows.append(row)
            print(f"  {name:4s} {split:18s} " + " ".join(f"{k}={v:.3f}" for k, v in row.items() if isinstance(v, float)))
    df = pd.DataFrame(rows)
    df.to_csv(out / "misma_real_devices.csv", index=False)
    return df


def _real_summary(df: pd.DataFrame) -> pd.DataFrame:
    cols = [c for c in df.columns if c not in ("device", "split")]
    ins = df[df.split == "in-sample"][cols].mean()
    held = df[df.split != "in-sample"][cols].mean()
    return pd.DataFrame({"in-sample mean (deg)": ins, "held-out mean (deg)": held})


# ---------------------------------------------------------------- entry
def run(cfg: DictConfig) -> dict:
    """Run the study described by ``cfg`` (conf/misma.yaml); returns the summary dict."""
    out = Path(cfg.out_dir)
    if not out.is_absolute():
        out = ROOT / out
    out.mkdir(parents=True, exist_ok=True)
    summary = {"config": OmegaConf.to_container(cfg, resolve=True)}
    lines = ["# MISMA study (issue #8)", "", "Command: `python -m experiments.misma` (config `conf/misma.yaml`).", ""]
    if cfg.simulated.enabled:
        sims = []
        for name, ov in cfg.simulated.variants.items():
            print(f"[simulated] rotating_drill variant {name!r} ...")
            s = simulated_variant(name, OmegaConf.to_container(ov), cfg.simulated, int(cfg.seed), out)
            sims.append(s)
            print(json.dumps({k: v for k, v in s.items() if k != "jacobian_singular_values"}, indent=1, default=float))
        summary["simulated"] = sims
        tab = pd.DataFrame([{k: v for k, v in s.items() if not isinstance(v, (dict, list))} for s in sims]).set_index("variant").T
        lines += ["## rotating_drill: MISMA vs SMA (same run)", "", tab.to_markdown(floatfmt=".4g"), ""]
        for s in sims:
            lines += [f"Baselines, mean |azimuth error| at the stops, variant {s['variant']}: "
                      + ", ".join(f"{k} {v:.3f} deg" for k, v in s["baselines_az_err_deg"].items()),
                      f"Relative singular values of the fitness Jacobian at the truth ({s['variant']}): "
                      + ", ".join(f"{v:.2g}" for v in s["jacobian_singular_values"]), ""]
    if cfg.real.enabled:
        print("[real] circuitpython-mag-cal devices ...")
        df = real_study(cfg.real, int(cfg.seed), out)
        summ = _real_summary(df)
        summ.to_csv(out / "misma_real_summary.csv")
        summary["real"] = summ.to_dict()
        lines += ["## 9 real devices: peer metric (deg), ours vs circuitpython-mag-cal", "",
                  df.to_markdown(index=False, floatfmt=".3f"), "", summ.to_markdown(floatfmt=".3f"), ""]
    (out / "misma_summary.md").write_text("\n".join(lines))
    (out / "misma_summary.json").write_text(json.dumps(summary, indent=1, default=float))
    print("\n".join(lines))
    return summary


@hydra.main(config_path="../conf", config_name="misma", version_base="1.3")
def main(cfg: DictConfig) -> None:
    """Hydra entry point: ``python -m experiments.misma [overrides]``."""
    run(cfg)


if __name__ == "__main__":
    main()
