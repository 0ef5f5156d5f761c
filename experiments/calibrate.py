"""Calibration front door for a user's recording: ``conf/calibrate.yaml`` -> :mod:`icgo.studies.calibration`.

    python -m experiments.calibrate data=shots.csv                       # contract CSV with a group column
    python -m experiments.calibrate data=device.json                     # circuitpython-mag-cal, fixture layout
    python -m experiments.calibrate data=raw.json mag_axes=+x+y-z grav_axes=-y-x+z   # the raw layout
    python -m experiments.calibrate data=device.json groups=[8-15,16-23]   # the rolls given (default: found)
    python -m experiments.calibrate data=bundled                         # the 9 bundled devices -> results/

Reads the shots (:func:`icgo.io.shots.read_shots`: the rolls found from the data or given, each checked),
fits every method (ellipsoid, 12-parameter least squares + axis, MISMA + axis, the
regularised joint fit, least squares + axis + a RELM on the residual, the peer package side by
side), scores each in-sample and held out, checks each for physical sanity, recommends one
(:func:`icgo.studies.calibration.recommend`), and writes into the run
directory ``report.md`` (the rolls, the scores, the recommendation), ``calibration.csv`` (every fit: score
and sanity), ``calibration.json`` (the run's record, with ``recommendation``), one
figure per recording and ``models/<recording>_<method>.json`` (the in-sample
calibrations; ``python -m experiments.apply model=<run dir> data=...`` applies the recommended one). Files
are staged and moved into place only when all are written; a used run directory is refused unless
``overwrite=true``. JAX's compilation cache is on (``jax_cache_dir``). A bad setting: one line, exit 2; bad
data: one line, exit 1.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import hydra
import numpy as np
from omegaconf import DictConfig, OmegaConf

from experiments._entry import enable_jax_cache, one_line, one_line_errors
from icgo.core.errors import DataError, SettingError

ROOT = Path(__file__).resolve().parents[1]
#: Settings of the entry point, not of the study (excluded from CalibrationConfig).
ENTRY_KEYS = ("data", "mag_axes", "grav_axes", "groups", "results_dir", "jax_cache_dir", "overwrite")
#: Largest recording calibrated: its shots and its rolled groups (each group is one leave-one-group-out fold of
#: every method, vmapped). Measured peak memory at both limits: 2.1 GB (docs/data.md); 2,000 shots in 250
#: groups passed 24 GB.
MAX_CAL_SHOTS = 400
MAX_CAL_GROUPS = 50
#: Seed of the fits' PRNG key (split once per recording and split; MISMA is the only fit that draws from it).
SEED = 0


def results_path(cfg: DictConfig) -> Path:
    """``results_dir`` (relative to the repository root)."""
    res = Path(str(cfg.results_dir))
    return res if res.is_absolute() else ROOT / res


def check_size(rec, src: str) -> None:
    """DataError naming the file when a recording exceeds :data:`MAX_CAL_SHOTS` or :data:`MAX_CAL_GROUPS`."""
    from icgo.methods.calibration import MIN_ROLLED_SHOTS

    n = len(rec.frame)
    groups = rec.frame["group"].value_counts() if "group" in rec.frame.columns else None
    rolled = 0 if groups is None else int((groups >= MIN_ROLLED_SHOTS).sum())
    if rolled == 0:
        raise DataError(f"{src}: no rolled group ({MIN_ROLLED_SHOTS} or more shots about one pointing direction, "
                        f"turned about it); calibration needs at least one")
    if n > MAX_CAL_SHOTS or rolled > MAX_CAL_GROUPS:
        raise DataError(f"{src}: {n} shots in {rolled} rolled groups; calibrate takes at most {MAX_CAL_SHOTS} shots "
                        f"and {MAX_CAL_GROUPS} rolled groups (its memory grows with both; docs/data.md): split the "
                        f"recording")


def study_config(cfg: DictConfig):
    """:class:`icgo.studies.calibration.CalibrationConfig` of a composed config (unknown keys refused)."""
    from icgo.core.settings import config_from_mapping
    from icgo.studies.calibration import CalibrationConfig

    values = {k: v for k, v in OmegaConf.to_container(cfg, resolve=True).items() if k not in ENTRY_KEYS}
    return config_from_mapping(CalibrationConfig, values, "conf/calibrate.yaml")


def load(cfg: DictConfig) -> dict:
    """name -> Recording with a checked ``group`` column, from ``data=`` (raises SettingError / DataError)."""
    from icgo.io import recording as io
    from icgo.studies.shots import read_shots

    data = cfg.data
    if data is None or str(data) == "":
        raise SettingError("data= is required: a contract CSV with a group column, a circuitpython-mag-cal JSON, "
                           "or 'bundled'")
    if not isinstance(data, str):
        raise SettingError(f"data={data!r}: must be a path (a contract CSV or a circuitpython-mag-cal JSON) or "
                           f"'bundled'")
    settings = {k: (OmegaConf.to_container(cfg[k]) if OmegaConf.is_list(cfg[k]) else cfg[k])
                for k in ("mag_axes", "grav_axes", "groups")}
    if data == "bundled":
        if any(v is not None for v in settings.values()):
            raise SettingError("mag_axes / grav_axes / groups apply to a file, not to data=bundled (the 9 devices' "
                               "rolls are the peer's shots 8-15 and 16-23)")
        return {name: io.load_mag_cal_device(name) for name in io.mag_cal_devices()}
    rec = read_shots(data, **settings)
    check_size(rec, data)
    return {Path(data).stem: rec}


def figure(rec, models: dict, path: Path) -> None:
    """Per shot: pointing direction raw vs calibrated, dip and |B| per method (sound fits solid, degenerate dashed)."""
    from matplotlib.figure import Figure  # not pyplot: no backend machinery, half the import time

    from icgo.methods.calibration import pointing_directions
    from icgo.physics.qc import measured_dip_deg
    from icgo.studies.calibration import model_sanity

    G, B = rec.G, rec.B
    fig = Figure(figsize=(16, 4.5))
    ax = fig.subplots(1, 3)

    def direction(Gc, Bc):
        d = pointing_directions(Gc, Bc)
        return np.mod(np.degrees(np.arctan2(d[:, 1], d[:, 0])), 360.0), np.degrees(np.arcsin(np.clip(-d[:, 2], -1, 1)))

    az, inc = direction(G, B)
    ax[0].plot(az, inc, "kx", label="raw")
    shots = np.arange(len(G))
    for i, (m, c) in enumerate(models.items()):
        Gc, Bc = c.corrected(G, B)
        ls = "--" if model_sanity(c, G, B).degenerate else "-"
        a, n = direction(Gc, Bc)
        ax[0].plot(a, n, "o", ms=3, color=f"C{i}", label=m)
        ax[1].plot(shots, measured_dip_deg(Gc, Bc), ls, marker=".", color=f"C{i}", label=m)
        bn = np.linalg.norm(Bc, axis=1)
        ax[2].plot(shots, bn / bn.mean(), ls, marker=".", color=f"C{i}", label=m)
    ax[0].set(xlabel="azimuth of the pointing axis (deg, magnetic)", ylabel="inclination (deg)",
              title="per-shot direction, raw and calibrated")
    ax[1].set(xlabel="shot", ylabel="dip (deg)", title="dip per shot (one field: flat)")
    ax[2].set(xlabel="shot", ylabel="|B| / mean", title="|B| per shot (one field: flat)")
    for a in ax:
        a.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def rolls_section(name: str, rec, model) -> list[str]:
    """The report's lines on one recording's groups: every roll (shots, pointing direction, roll span, how
    far its shots leave the roll plane) and how the groups were made (the reader's notices)."""
    from icgo.io.grouping import roll_table
    from icgo.studies.calibration import roll_directions

    t = roll_table(rec.frame).merge(roll_directions(model, rec.G, rec.B, rec.frame["group"].to_numpy()),
                                    on="group", suffixes=("_raw", ""))
    t = t.rename(columns={"inclination_deg_raw": "raw inclination (deg)", "azimuth_deg": "azimuth (deg, magnetic)",
                          "inclination_deg": "inclination (deg)", "roll_span_deg": "roll span (deg)",
                          "plane_g": "off plane G (g)", "plane_b": "off plane B (|B|)",
                          "axis_to_z_deg": "axis to tool z (deg)", "spread_deg": "spread (deg)"})
    n_single = int((rec.frame.groupby("group").size() < 2).sum())
    lines = [(f"- `{name}`: {len(rec.frame)} shots, {len(t)} roll(s) and {n_single} single shot(s); "
              f"{rec.meta.get('description', '')}")]
    lines += [f"  - notice: {n}" for n in rec.notices]
    lines += ["", f"Rolls of `{name}` (direction and spread after the recommended calibration, `{model.method}`):",
              "", t.to_markdown(index=False, floatfmt=".4g"), ""]
    return lines


def protocol(df, config) -> str:
    """The protocol line of ``data=bundled``'s table (:func:`icgo.reporting.protocol.protocol_line`), from
    :func:`icgo.studies.calibration.evaluate`'s long table ``df`` and the run's ``config``."""
    from icgo.core.settings import config_overrides
    from icgo.reporting.protocol import protocol_line

    extra = config_overrides(config)
    command = ("`make calibration` (`python -m experiments.calibrate data=bundled`)" if not extra else
               f"`python -m experiments.calibrate data=bundled {' '.join(extra)}`")
    recordings = df["recording"].unique()
    held = df.loc[df["split"] != "in-sample", ["recording", "split"]].drop_duplicates()
    per_rec = held.groupby("recording").size().reindex(recordings, fill_value=0)
    lo, hi = int(per_rec.min()), int(per_rec.max())
    return protocol_line(
        command,
        f"one fit per recording, split and method (a score cell pools no repeats); `misma+axis` keeps the lowest "
        f"fitness of {config.misma_repeats} MISMA runs (population {config.misma_pop}, {config.misma_iter} "
        f"iterations) per fit; a recommendation's mean pools its recording's {lo if lo == hi else f'{lo}-{hi}'} "
        f"held-out split(s); the per-method means pool the sound fits of all {len(recordings)} recordings "
        f"({len(recordings)} in-sample and {len(held)} held-out fits per method), unpaired (each method's "
        "degenerate fits are left out)",
        "in-sample: fitted and scored on every shot of a recording; held out (`icgo.studies.calibration.splits`): "
        "each rolled group left out of the fit in turn and scored alone (a recording with one roll: its "
        "interleaved halves), the single shots always fitted; the joint fit's strength and the RELM's ridge are "
        "chosen by leave-one-group-out inside each split's training shots; the recommendation ranks the sound "
        "methods by the same held-out scores it reports (a selection: the winner's mean is optimistic)",
        f"no data seed (the {len(recordings)} bundled recordings, real shots); PRNGKey({SEED}) split once per "
        f"recording and split in table order, used only by MISMA (its {config.misma_repeats} runs split that key); "
        "every other fit and the peer are deterministic. No device is kept back: the joint fit's staging was chosen "
        "on these recordings' held-out means and the step counts checked on them (docs/calibrate.md); the sanity "
        "limits were fixed before any device was scored",
        "none: no p-value here; a recommendation's \"clear winner\" is a rule of thumb (its margin over the "
        "runner-up exceeds the standard error of its held-out mean), not a significance test. The paired Wilcoxon "
        "of `twelve+axis+relm` against the other methods over the held-out splits, Holm over those tests, is in "
        "docs/calibrate.md (from calibration_devices.csv)")


def report(df, summ, recordings: dict, label: str, recs: dict, models: dict, protocol_line: str | None = None) -> str:
    """The Markdown report: the rolls, the recommendation, the scores (degenerate marked), the per-method summary;
    ``protocol_line`` (:func:`protocol`) under the title when given."""
    from icgo.methods.cal_sanity import limits_sentence
    from icgo.physics.rolls import AXIS_TO_Z_DEG, MIN_SPAN_DEG, PLANE_TOL_B, PLANE_TOL_G
    from icgo.studies.calibration import wide

    lines = [f"# Magnetometer calibration: {label}", ""] + ([protocol_line, ""] if protocol_line else [])
    lines += ["## Recommendation", ""]
    lines += [f"- `{name}`: {r['sentence']}" for name, r in recs.items()]
    lines += ["", "`python -m experiments.apply model=<this run directory> data=<survey.csv>` applies it"
              + (" (the run holds several recordings: name one model file instead)" if len(recs) > 1 else "") + ".",
              "", "## Shots and rolls", "",
              (f"A roll: consecutive shots whose raw gravity and field each stay within {PLANE_TOL_G:g} g and "
               f"{PLANE_TOL_B:g} |B| of one plane (the pointing axis' components constant), turning about one axis "
               f"within {AXIS_TO_Z_DEG:g} deg of tool z shared by all rolls, over at least {MIN_SPAN_DEG:g} deg "
               "(`icgo.physics.rolls`, docs/calibrate.md)."), ""]
    for name, rec in recordings.items():
        lines += rolls_section(name, rec, models[name])
    lines += ["## Scores", "",
              "Score: the peer's metric (circuitpython-mag-cal `accuracy`, deg: spread of the pointing direction "
              "within each rolled group). In-sample: fitted and scored on every shot; held-out group g: fitted "
              "without group g, scored on it. " + limits_sentence(), "",
              wide(df).to_markdown(index=False), "",
              "## Per method (means over the sound fits; maxima over all fits)", "",
              summ.to_markdown(floatfmt=".3f"), ""]
    return "\n".join(lines) + "\n"


def record(cfg: DictConfig, config, recordings: dict, recs: dict, seconds: float) -> dict:
    """The run's machine-readable record (``calibration.json``): settings, recordings and their rolls, and
    the recommendation (``recommendation`` for a one-recording run, ``recommendations`` per recording)."""
    from icgo.core.settings import config_to_mapping
    from icgo.io.grouping import roll_table

    out = {"kind": "calibration_run", "data": str(cfg.data), "config": config_to_mapping(config),
           "recordings": {name: {"shots": int(len(rec.frame)), "description": rec.meta.get("description", ""),
                                 "rolls": roll_table(rec.frame).to_dict(orient="records"),
                                 "notices": list(rec.notices)} for name, rec in recordings.items()},
           "recommendations": {n: {k: v for k, v in r.items() if k != "sentence"} for n, r in recs.items()},
           "wall_time_s": seconds}
    if len(recs) == 1:
        out["recommendation"] = next(iter(out["recommendations"].values()))
    return out


def run(cfg: DictConfig, out: Path, config=None, keep=()) -> None:
    """Load, fit, score, check, recommend, and write the run directory (all or nothing: :class:`icgo.io.files.Output`;
    a used directory is refused before anything is computed, unless ``overwrite=true``)."""
    t0 = time.perf_counter()
    enable_jax_cache(cfg.get("jax_cache_dir"))
    import jax

    import icgo  # noqa: F401  (float64)
    from experiments._entry import bool_setting, write_hydra_record
    from icgo.io.files import Output
    from icgo.reporting.records import CALIBRATION_FILE
    from icgo.studies import calibration
    from icgo.survey.verdict import calibrate_verdict

    config = study_config(cfg) if config is None else config
    output = Output(out, setting="hydra.run.dir", overwrite=bool_setting(cfg, "overwrite"), keep=keep,
                    writer="experiments.calibrate").check()
    if str(cfg.data) == "bundled":  # results/ checked now, not after the fits
        Output(results_path(cfg), setting="results_dir", shared=True).check()
    recordings = load(cfg)
    df, models = calibration.evaluate(recordings, config, jax.random.PRNGKey(SEED))
    summ = calibration.summary(df)
    try:
        recs = {name: calibration.recommend(df, name) for name in recordings}
    except ValueError as e:
        raise DataError(str(e)) from None
    chosen = {name: models[calibration.model_label(name, r["method"])] for name, r in recs.items()}
    bundled = str(cfg.data) == "bundled"
    label = "the 9 bundled circuitpython-mag-cal devices" if bundled else str(cfg.data)
    text = report(df, summ, recordings, label, recs, chosen, protocol(df, config) if bundled else None)
    run_record = record(cfg, config, recordings, recs, time.perf_counter() - t0)
    verdict = calibrate_verdict(recommendation=run_record.get("recommendation"), n_models=len(models),
                                run_dir=str(out), n_degenerate=int(df["degenerate"].sum()), n_fits=len(df),
                                held_out=df[df["split"] != "in-sample"].groupby("method")["score_deg"].mean().to_dict())
    with output.staged(last=(CALIBRATION_FILE,)) as stage:  # the record last: a run directory with it is complete
        (stage / "models").mkdir()
        write_hydra_record(stage, cfg)
        (stage / "report.md").write_text(text + "\n" + "\n".join(verdict.markdown()) + "\n")
        df.to_csv(stage / "calibration.csv", index=False, float_format="%.6g")
        for name, rec in recordings.items():
            figure(rec, {m: models[calibration.model_label(name, m)] for m in calibration.METHODS},
                   stage / f"{name}.png")
        for label_, model in models.items():
            model.save(stage / "models" / label_)
        (stage / CALIBRATION_FILE).write_text(json.dumps(run_record, indent=2, allow_nan=False) + "\n")
    if bundled:
        from icgo.io.recording import atomic_write_texts

        res = results_path(cfg)
        res.mkdir(parents=True, exist_ok=True)
        atomic_write_texts([(res / "calibration_devices.md", text.replace(
                                "# Magnetometer calibration:", "# Magnetometer calibration (`python -m experiments."
                                "calibrate data=bundled`):")),
                            (res / "calibration_devices.csv", df.to_csv(index=False, float_format="%.6g"))])
        print(f"wrote {res / 'calibration_devices.md'}")
    print(text)
    print(f"run directory: {out} ({len(models)} calibrations in models/; {time.perf_counter() - t0:.1f} s)")
    print(verdict.text())


@hydra.main(config_path="../conf", config_name="calibrate", version_base="1.3")
@one_line_errors
def main(cfg: DictConfig) -> None:
    """Hydra entry point; a bad setting exits 2, bad data exits 1, each with one line."""
    from hydra.core.hydra_config import HydraConfig

    from experiments._entry import hydra_keep

    try:
        config = study_config(cfg)
    except ValueError as e:
        raise SettingError(one_line(e)) from None
    run(cfg, Path(HydraConfig.get().runtime.output_dir), config, keep=hydra_keep())


def cli() -> None:
    from experiments._entry import preflight

    preflight("calibrate")
    main()


if __name__ == "__main__":
    from experiments._entry import guarded

    guarded(cli)
