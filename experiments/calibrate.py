"""Calibration front door for a user's recording (issue 16): ``conf/calibrate.yaml`` -> :mod:`icgo.studies.calibration`.

    python -m experiments.calibrate data=shots.csv                       # contract CSV with a group column
    python -m experiments.calibrate data=device.json                     # circuitpython-mag-cal, fixture layout
    python -m experiments.calibrate data=raw.json mag_axes=+x+y-z grav_axes=-y-x+z   # the raw layout
    python -m experiments.calibrate data=bundled                         # the 9 bundled devices -> results/

Fits every method (ellipsoid, 12-parameter least squares + axis, MISMA + axis, the
joint fit, least squares + axis + a RELM on the residual, the peer package side by
side), scores each in-sample and with each
rolled group held out, checks each for physical sanity, and writes into the run
directory ``report.md``, ``calibration.csv`` (every fit: score and sanity), one
figure per recording and ``models/<recording>_<method>.json`` (the in-sample
calibrations; ``python -m experiments.apply model=... data=...`` applies one). Files
are staged and moved into place only when all are written. A bad setting: one line,
exit 2; bad data: one line, exit 1.
"""

from __future__ import annotations

from pathlib import Path

import hydra
import numpy as np
from omegaconf import DictConfig, OmegaConf

from experiments._entry import one_line, one_line_errors
from icgo.core.errors import DataError, SettingError

ROOT = Path(__file__).resolve().parents[1]
#: Settings of the entry point, not of the study (excluded from CalibrationConfig).
ENTRY_KEYS = ("data", "mag_axes", "grav_axes", "results_dir", "overwrite")
#: Largest recording calibrated: its shots and its rolled groups (each group is one leave-one-group-out fold of
#: every method, vmapped). Measured peak memory at both limits: 2.1 GB (docs/data.md); 2,000 shots in 250
#: groups passed 24 GB.
MAX_CAL_SHOTS = 400
MAX_CAL_GROUPS = 50


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
    """name -> Recording with a ``group`` column, from ``data=`` (raises icgo.io.recording.DataError / ValueError)."""
    from icgo.io import recording as io
    from icgo.methods.calibration import MIN_ROLLED_SHOTS

    data = cfg.data
    if data is None or data == "":
        raise SettingError("data= is required: a contract CSV with a group column, a circuitpython-mag-cal JSON, "
                           "or 'bundled'")
    if not isinstance(data, str):
        raise SettingError(f"data={data!r}: must be a path (a contract CSV or a circuitpython-mag-cal JSON) or "
                           f"'bundled'")
    data = str(data)
    axes = {"mag_axes": cfg.mag_axes, "grav_axes": cfg.grav_axes}
    if data == "bundled":
        if any(v is not None for v in axes.values()):
            raise SettingError("mag_axes / grav_axes apply to a raw-layout JSON file, not to data=bundled")
        return {name: io.load_mag_cal_device(name) for name in io.mag_cal_devices()}
    if data.lower().endswith(".json"):
        from icgo.io.mag_cal_json import AxesNotApplicable, parse_axes, read_mag_cal_json

        for k, v in axes.items():  # each named by its own key (an unset grav_axes follows mag_axes)
            if v is not None:
                try:
                    parse_axes(str(v), k)
                except DataError as e:
                    raise SettingError(str(e)) from None
        try:
            rec = read_mag_cal_json(data, **{k: (None if v is None else str(v)) for k, v in axes.items()})
        except AxesNotApplicable as e:  # a bad setting, as for a CSV
            raise SettingError(str(e)) from None
    else:
        if any(v is not None for v in axes.values()):
            raise SettingError("mag_axes / grav_axes apply to a raw-layout JSON file; a contract CSV is in the tool "
                             "frame already")
        rec = io.read_recording(data, require_meta=False, require_reference=False)
        if "group" not in rec.frame.columns:
            io.fail(data, "no 'group' column: calibration needs shots grouped by true direction "
                           f"(rolled groups of {MIN_ROLLED_SHOTS} or more shots about one pointing direction)")
    check_size(rec, data)
    return {Path(data).stem: rec}


def figure(rec, models: dict, path: Path) -> None:
    """Per shot: pointing direction raw vs calibrated, dip and |B| per method (sound fits solid, degenerate dashed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from icgo.methods.calibration import pointing_directions
    from icgo.physics.qc import measured_dip_deg
    from icgo.studies.calibration import model_sanity

    G, B = rec.G, rec.B
    fig, ax = plt.subplots(1, 3, figsize=(16, 4.5))

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
    ax[0].set(xlabel="azimuth of the pointing axis (deg, magnetic)",
              ylabel="elevation of the pointing axis (deg, up +; inclination = 90 - elevation)",
              title="per-shot direction, raw and calibrated")
    ax[1].set(xlabel="shot", ylabel="dip (deg)", title="dip per shot (one field: flat)")
    ax[2].set(xlabel="shot", ylabel="|B| / mean", title="|B| per shot (one field: flat)")
    for a in ax:
        a.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def report(df, summ, recordings: dict, label: str) -> str:
    """The Markdown report: the scores (degenerate marked), the per-method summary, the sanity limits."""
    from icgo.methods.cal_sanity import limits_sentence
    from icgo.studies.calibration import wide

    lines = [f"# Magnetometer calibration: {label}", "",
             "Score: the peer's metric (circuitpython-mag-cal `accuracy`, deg: spread of the pointing direction "
             "within each rolled group). In-sample: fitted and scored on every shot; held-out group g: fitted "
             "without group g, scored on it. " + limits_sentence(), "",
             wide(df).to_markdown(index=False), "",
             "## Per method (means over the sound fits; maxima over all fits)", "",
             summ.to_markdown(floatfmt=".3f"), ""]
    for name, rec in recordings.items():
        lines += [f"- `{name}`: {len(rec.frame)} shots; {rec.meta.get('description', '')}"]
    return "\n".join(lines) + "\n"


def run(cfg: DictConfig, out: Path, config=None, keep=()) -> None:
    """Load, fit, score, check, and write the run directory (all or nothing: :class:`icgo.io.files.Output`;
    a used directory is refused before anything is computed, unless ``overwrite=true``)."""
    import jax

    import icgo  # noqa: F401  (float64)
    from experiments._entry import bool_setting, write_hydra_record
    from icgo.io.files import Output
    from icgo.studies import calibration

    config = study_config(cfg) if config is None else config
    output = Output(out, setting="hydra.run.dir", overwrite=bool_setting(cfg, "overwrite"), keep=keep,
                    writer="experiments.calibrate").check()
    if str(cfg.data) == "bundled":  # results/ checked now, not after the fits
        Output(results_path(cfg), setting="results_dir", shared=True).check()
    recordings = load(cfg)
    df, models = calibration.evaluate(recordings, config, jax.random.PRNGKey(0))
    summ = calibration.summary(df)
    label = "the 9 bundled circuitpython-mag-cal devices" if str(cfg.data) == "bundled" else str(cfg.data)
    text = report(df, summ, recordings, label)
    with output.staged(last=("report.md",)) as stage:
        (stage / "models").mkdir()
        write_hydra_record(stage, cfg)
        (stage / "report.md").write_text(text)
        df.to_csv(stage / "calibration.csv", index=False, float_format="%.6g")
        for name, rec in recordings.items():
            figure(rec, {m: models[calibration.model_label(name, m)] for m in calibration.METHODS},
                   stage / f"{name}.png")
        for label_, model in models.items():
            model.save(stage / "models" / label_)
    if str(cfg.data) == "bundled":
        from icgo.io.recording import atomic_write_texts

        res = results_path(cfg)
        res.mkdir(parents=True, exist_ok=True)
        atomic_write_texts([(res / "calibration_devices.md", text.replace(
                                "# Magnetometer calibration:", "# Magnetometer calibration (`python -m experiments."
                                "calibrate data=bundled`):")),
                            (res / "calibration_devices.csv", df.to_csv(index=False, float_format="%.6g"))])
        print(f"wrote {res / 'calibration_devices.md'}")
    from icgo.io.recording import atomic_write_texts
    from icgo.survey.verdict import calibrate_verdict, recommendation_in

    verdict = calibrate_verdict(recommendation=recommendation_in(out), n_models=len(models), run_dir=str(out),
                                n_degenerate=int(df["degenerate"].sum()), n_fits=len(df),
                                held_out=df[df["split"] != "in-sample"].groupby("method")["score_deg"].mean().to_dict())
    atomic_write_texts([(out / "report.md", text + "\n" + "\n".join(verdict.markdown()) + "\n")])
    print(text)
    print(f"run directory: {out} ({len(models)} calibrations in models/)")
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
