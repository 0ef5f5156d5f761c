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

import os
import shutil
import sys
from pathlib import Path

import hydra
import numpy as np
from omegaconf import DictConfig, OmegaConf

from experiments._entry import EXIT_CONFIG, one_line
from icgo.core.errors import SettingError

ROOT = Path(__file__).resolve().parents[1]
#: Settings of the entry point, not of the study (excluded from CalibrationConfig).
ENTRY_KEYS = ("data", "mag_axes", "grav_axes", "results_dir")


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
    if data is None or str(data) == "":
        raise SettingError("data= is required: a contract CSV with a group column, a circuitpython-mag-cal JSON, "
                         "or 'bundled'")
    data = str(data)
    axes = {"mag_axes": cfg.mag_axes, "grav_axes": cfg.grav_axes}
    if data == "bundled":
        if any(v is not None for v in axes.values()):
            raise SettingError("mag_axes / grav_axes apply to a raw-layout JSON file, not to data=bundled")
        return {name: io.load_mag_cal_device(name) for name in io.mag_cal_devices()}
    if data.lower().endswith(".json"):
        from icgo.io.mag_cal_json import AxesNotApplicable, read_mag_cal_json

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


def run(cfg: DictConfig, out: Path, config=None) -> None:
    """Load, fit, score, check, and write the run directory (staged, then moved into place)."""
    import jax

    import icgo  # noqa: F401  (float64)
    from icgo.studies import calibration

    config = study_config(cfg) if config is None else config
    recordings = load(cfg)
    df, models = calibration.evaluate(recordings, config, jax.random.PRNGKey(0))
    summ = calibration.summary(df)
    label = "the 9 bundled circuitpython-mag-cal devices" if str(cfg.data) == "bundled" else str(cfg.data)
    text = report(df, summ, recordings, label)
    stage = out / ".staging"
    shutil.rmtree(stage, ignore_errors=True)
    (stage / "models").mkdir(parents=True)
    try:
        (stage / "report.md").write_text(text)
        df.to_csv(stage / "calibration.csv", index=False, float_format="%.6g")
        for name, rec in recordings.items():
            figure(rec, {m: models[calibration.model_label(name, m)] for m in calibration.METHODS},
                     stage / f"{name}.png")
        for label_, model in models.items():
            model.save(stage / "models" / label_)
        for f in sorted(stage.rglob("*")):
            if f.is_file():
                dest = out / f.relative_to(stage)
                dest.parent.mkdir(parents=True, exist_ok=True)
                os.replace(f, dest)
    finally:
        shutil.rmtree(stage, ignore_errors=True)
    if str(cfg.data) == "bundled":
        from icgo.io.recording import atomic_write_texts

        res = Path(str(cfg.results_dir))
        res = res if res.is_absolute() else ROOT / res
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
def main(cfg: DictConfig) -> None:
    """Hydra entry point; a bad setting exits 2, bad data exits 1, each with one line."""
    from hydra.core.hydra_config import HydraConfig

    from icgo.core.errors import DataError, SettingError

    try:
        config = study_config(cfg)
    except ValueError as e:
        print(f"error: {one_line(e)}", file=sys.stderr)
        raise SystemExit(EXIT_CONFIG) from None
    try:
        run(cfg, Path(HydraConfig.get().runtime.output_dir), config)
    except (DataError, ValueError) as e:  # DataError and SettingError are ValueErrors (icgo.core.errors)
        print(f"error: {one_line(e)}", file=sys.stderr)
        raise SystemExit(EXIT_CONFIG if isinstance(e, SettingError) else 1) from None


if __name__ == "__main__":
    from experiments._entry import preflight

    preflight("calibrate")
    main()
