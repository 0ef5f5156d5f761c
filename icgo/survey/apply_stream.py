"""A streamed survey's survey-level result in memory bounded by the chunk, not the file.

:func:`icgo.survey.apply.summarise` reads every station's arrays (:attr:`icgo.survey.apply.Rows.keep`) at once;
for a survey read in chunks (:func:`icgo.io.stream.read_chunks`) that is a few floats per station, so memory
would grow with the file. :class:`StreamedSurvey` folds each chunk's :class:`~icgo.survey.apply.Rows` in as it
comes and keeps only:

* sums and moments (count, mean, sum of squared deviations, merged by Chan et al.'s pairwise update) for the
  metrics (MAE, RMSE, R^2, R^2 of the error: eqs. 19-21), the field's spread (:func:`icgo.survey.apply.one_field_doubt`)
  and the interval's coverage: the whole survey's values up to the order of the sums (relative 1e-15);
* the values whose *median* the result needs (the |B| and dip deviations after correction, the reference angles'
  radians test), appended to files in a scratch directory (:class:`DiskColumn`) and their exact medians found by
  selection in passes over the file (:func:`DiskColumn.median`: ``np.median``'s value, bitwise);
* the positions by minimum curvature (welleng) chunk by chunk, each chunk tied on at the last station of the one
  before (:class:`StreamedPositions`), written to the positions file as they come.

:meth:`StreamedSurvey.result` gives what :func:`icgo.survey.apply.summarise` gives for the whole survey (its
``stations`` empty: nothing per station is held) and :meth:`StreamedSurvey.verdict` what
:func:`icgo.survey.verdict.survey_verdict` gives. Measured (``python -m experiments.bench --rows ...
--rows-commands apply``): results/performance.md.
"""

from __future__ import annotations

import re
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

from icgo.core.errors import DataError
from icgo.physics.frames import angle_diff
from icgo.survey.apply import (NO_REFERENCE_NOTICE, NO_SENSORS_NOTICE, RADIANS_MAX, CorrectedSurvey, Rows,
                               field_doubt_line, radians_line)
from icgo.survey.trajectory import check_md, positions, position_summary

#: Values a :class:`DiskColumn` reads per step, and the most it selects from in memory (float64: 16 MiB).
BLOCK = 1 << 21
_BINS = 4096
_ROW = re.compile(r"\brow (\d+)\b")


class Moments:
    """Count, mean and sum of squared deviations of a stream of float64 values (Chan et al. 1979 merge).

    ``np.mean`` / ``np.std`` (population) of all the values up to rounding (relative ~1e-15).
    """

    def __init__(self):
        self.n, self.mean, self.m2 = 0, 0.0, 0.0

    def add(self, x) -> None:
        x = np.asarray(x, np.float64)
        nb = x.size
        if nb == 0:
            return
        mb = float(np.mean(x))
        m2b = float(np.sum((x - mb) ** 2))
        n = self.n + nb
        delta = mb - self.mean
        self.mean += delta * nb / n
        self.m2 += m2b + delta * delta * self.n * nb / n
        self.n = n

    def std(self) -> float:
        return float(np.sqrt(self.m2 / self.n)) if self.n else float("nan")


class DiskColumn:
    """A float64 column appended to a file chunk by chunk; its exact median by selection over the file.

    Args:
        path: the file (created empty).
    """

    def __init__(self, path: Path):
        self.path = Path(path)
        self.path.write_bytes(b"")
        self.n = 0
        self.finite = True

    def add(self, x) -> None:
        x = np.ascontiguousarray(x, np.float64)
        self.finite = self.finite and bool(np.all(np.isfinite(x)))
        with open(self.path, "ab") as f:
            f.write(x.tobytes())
        self.n += x.size

    def _blocks(self):
        with open(self.path, "rb") as f:
            while True:
                b = np.fromfile(f, np.float64, BLOCK)
                if not b.size:
                    return
                yield b

    def kth(self, k: int) -> float:
        """The k-th smallest value (0-based) of a column of finite values, in passes of :data:`BLOCK` values: a
        histogram narrows the range that holds it until at most :data:`BLOCK` values lie in it, then
        ``np.partition`` of those."""
        lo, hi = np.inf, -np.inf
        for b in self._blocks():
            lo, hi = min(lo, float(b.min())), max(hi, float(b.max()))
        below = 0                                   # values < lo; the k-th lies in [lo, hi]
        while True:
            inside = sum(int(np.count_nonzero((b >= lo) & (b <= hi))) for b in self._blocks())
            if inside <= BLOCK or lo == hi:
                if lo == hi:
                    return lo
                vals = np.concatenate([b[(b >= lo) & (b <= hi)] for b in self._blocks()])
                return float(np.partition(vals, k - below)[k - below])
            if np.nextafter(lo, np.inf) >= hi:      # two adjacent floats: count the lower one
                n_lo = sum(int(np.count_nonzero(b == lo)) for b in self._blocks())
                return lo if k - below < n_lo else hi
            edges = np.linspace(lo, hi, _BINS + 1)
            counts = np.zeros(_BINS, np.int64)
            for b in self._blocks():
                v = b[(b >= lo) & (b <= hi)]
                counts += np.bincount(np.clip(np.searchsorted(edges, v, side="right") - 1, 0, _BINS - 1),
                                      minlength=_BINS)
            cum = np.cumsum(counts)
            j = int(np.searchsorted(cum, k - below, side="right"))
            below += int(cum[j - 1]) if j else 0
            lo, hi = float(edges[j]), (hi if j == _BINS - 1 else float(np.nextafter(edges[j + 1], -np.inf)))

    def median(self) -> float:
        """``np.median`` of the column: NaN when it holds a NaN or nothing, else the middle value (the mean of the
        two middle values for an even count)."""
        if not self.n or not self.finite:
            return float("nan")
        if self.n % 2:
            return self.kth(self.n // 2)
        return float((self.kth(self.n // 2 - 1) + self.kth(self.n // 2)) / 2)


class StreamedPositions:
    """Positions by minimum curvature (welleng, :func:`icgo.survey.trajectory.positions`) of a survey given chunk by
    chunk: each chunk is tied on at the last station of the one before, and its rows are appended to ``out_csv``.
    The first error (a measured depth that does not increase) stops it: the file is removed, :attr:`error` holds the
    line, with the row counted from the survey's start."""

    def __init__(self, out_csv: Path):
        self.out_csv = Path(out_csv)
        self.last = None            # (md, {series: (inc, azi, (n, e, tvd))}) of the last station
        self.rows = 0
        self.error = None
        self.has_ref = True

    def add(self, k: dict) -> None:
        if self.error is not None:
            return
        md = np.asarray(k["md"], np.float64)
        series = {"raw": (k["inc_raw"], k["azi_raw"]), "cor": (k["inc_cor"], k["azi_cor"])}
        self.has_ref = self.has_ref and "inc_ref" in k and "azi_ref" in k
        if self.has_ref:
            series["ref"] = (k["inc_ref"], k["azi_ref"])
        lead = 0 if self.last is None else 1
        mds = md if self.last is None else np.concatenate([[self.last[0]], md])
        try:
            if len(mds) >= 2:
                check_md(mds)
        except DataError as e:
            shift = self.rows - lead
            self.error = _ROW.sub(lambda m: f"row {int(m.group(1)) + shift}", str(e), count=1)
            self.out_csv.unlink(missing_ok=True)
            return
        frames, last = {}, {}
        for name, (inc, azi) in series.items():
            inc, azi = np.asarray(inc, np.float64), np.asarray(azi, np.float64)
            if self.last is not None:
                li, la, start = self.last[1][name]
                inc, azi = np.concatenate([[li], inc]), np.concatenate([[la], azi])
            else:
                start = (0.0, 0.0, 0.0)
            pos = (positions(mds, inc, azi, start=start) if len(mds) >= 2 else
                   pd.DataFrame({"north_m": [start[0]], "east_m": [start[1]], "tvd_m": [start[2]]}))
            frames[name] = pos.iloc[lead:].reset_index(drop=True)
            last[name] = (float(inc[-1]), float(azi[-1]), tuple(float(v) for v in pos.iloc[-1]))
        self.last = (float(mds[-1]), last)
        table = pd.concat([frames["raw"].add_suffix("_raw").rename(columns=lambda c: c.replace("_m_raw", "_raw_m")),
                           frames["cor"]], axis=1)
        table.to_csv(self.out_csv, index=False, lineterminator="\n", header=not self.rows,
                     mode="a" if self.rows else "w")
        self.rows += len(md)

    def summary(self) -> dict | None:
        """:func:`icgo.survey.trajectory.position_change`'s summary of the whole survey (None after an error);
        raises the error as :class:`DataError` where there is one."""
        if self.error is not None:
            raise DataError(self.error)
        if self.rows < 2:
            check_md(np.zeros(self.rows))         # the whole survey's own line: positions need two stations
        one = {name: pd.DataFrame([pos], columns=["north_m", "east_m", "tvd_m"])
               for name, (_, _, pos) in self.last[1].items()}
        return position_summary(self.last[0], self.rows, one["raw"], one["cor"], one.get("ref"))


class StreamedSurvey:
    """The survey-level sums of a streamed survey (module doc), its scratch files in a temporary directory.

    Use as a context manager (the scratch directory is removed on exit); :meth:`add` each chunk's Rows in order.

    Args:
        positions_csv: where the positions go when the survey has measured depth.
    """

    def __init__(self, positions_csv: Path):
        self._tmp = tempfile.TemporaryDirectory(prefix="icgo-apply-")
        self.scratch = Path(self._tmp.name)
        self.positions = StreamedPositions(positions_csv)
        self.n = 0
        self.keys: set | None = None
        self.moments: dict[str, Moments] = {}
        self.sums: dict[str, float] = {}
        self.columns: dict[str, DiskColumn] = {}
        self.radians: dict[str, dict] = {}
        self.domain: dict = {}
        self.qc = None
        self.all_qc = True
        self.interval = None
        self.has_md = True

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._tmp.cleanup()

    def _moment(self, name, x):
        self.moments.setdefault(name, Moments()).add(x)

    def _sum(self, name, x):
        self.sums[name] = self.sums.get(name, 0.0) + float(np.sum(x))

    def _column(self, name, x):
        if name not in self.columns:
            self.columns[name] = DiskColumn(self.scratch / f"{name}.f64")
        self.columns[name].add(x)

    def add(self, rows: Rows) -> None:
        """Fold one chunk's :class:`~icgo.survey.apply.Rows` in (its table is written already)."""
        k = rows.keep
        # a key counts only when every chunk has it (a survey-level number needs every station)
        self.keys = set(k) if self.keys is None else self.keys & set(k)
        n = len(next(iter(k.values()))) if k else 0
        self.n += n
        for name in ("b_raw", "dip_raw", "b_corr", "dip_corr"):
            if name in k:
                self._moment(name, k[name])
        for name in ("db_nT", "ddip_deg"):
            if name in k:
                self._column(name, np.abs(k[name]))
        if "interval" in k and len(k["interval"]) and self.interval is None:
            self.interval = float(k["interval"][0])
        if "a_true" in k:
            a_true, a_comp = k["a_true"], k["a_comp"]
            err_raw = np.asarray(angle_diff(k["a_raw"], a_true)) if "a_raw" in k else np.zeros(len(a_true))
            self._moment("a_true", a_true)
            self._moment("err_raw", err_raw)
            for est in ("a_comp", "a_raw"):
                if est in k:
                    e = np.asarray(angle_diff(a_true, k[est]))
                    after = np.asarray(angle_diff(k[est], a_true))
                    self._sum(f"{est}_abs", np.abs(e))
                    self._sum(f"{est}_sq", e * e)
                    self._sum(f"{est}_after_sq", after * after)
            if "interval" in k:
                self._sum("covered", np.abs(np.asarray(angle_diff(a_comp, a_true))) <= k["interval"])
        for col, t, e in (("azimuth_deg", "a_true", "a_comp"), ("inclination_deg", "i_true", "i_est")):
            if t in k:
                self._radians(col, k[t], k[e])
        for q, (lo, hi) in rows.domain.items():
            self.domain[q] = [min(lo, self.domain[q][0]), max(hi, self.domain[q][1])] if q in self.domain else [lo, hi]
        if rows.qc and self.all_qc:
            self.qc = rows.qc if self.qc is None else {
                stage: {c: self.qc[stage][c] + rows.qc[stage][c] for c in self.qc[stage]} for stage in self.qc}
        else:
            self.all_qc = False
        self.has_md = self.has_md and "md" in k
        if self.has_md:
            self.positions.add(k)

    def _radians(self, col, reference, estimate) -> None:
        """The radians test's inputs (:func:`icgo.survey.apply.radians_doubt`): the finite rows' count and largest
        |reference|, and, while that stays within 2 pi, their differences read as degrees and as radians."""
        ref, est = np.asarray(reference, float), np.asarray(estimate, float)
        ok = np.isfinite(ref) & np.isfinite(est)
        ref, est = ref[ok], est[ok]
        r = self.radians.setdefault(col, {"n": 0, "max": 0.0})
        r["n"] += ref.size
        if ref.size:
            r["max"] = max(r["max"], float(np.max(np.abs(ref))))
        if r["max"] <= RADIANS_MAX:
            self._column(f"{col}_as_deg", np.abs(np.asarray(angle_diff(est, ref))))
            self._column(f"{col}_as_rad", np.abs(np.asarray(angle_diff(est, np.degrees(ref)))))

    def _radians_doubt(self, col) -> str | None:
        r = self.radians[col]
        if r["n"] < 3 or r["max"] > RADIANS_MAX:
            return None
        return radians_line(self.columns[f"{col}_as_deg"].median(), self.columns[f"{col}_as_rad"].median(), col)

    def _metrics(self, est: str) -> dict:
        n, s = self.n, self.sums
        with np.errstate(divide="ignore", invalid="ignore"):
            return {"mae": float(s[f"{est}_abs"] / n), "rmse": float(np.sqrt(s[f"{est}_sq"] / n)),
                    "r2": float(1.0 - np.float64(s[f"{est}_sq"]) / self.moments["a_true"].m2),
                    "r2_error": float(1.0 - np.float64(s[f"{est}_after_sq"]) / self.moments["err_raw"].m2)}

    def result(self, model, field) -> CorrectedSurvey:
        """What :func:`icgo.survey.apply.summarise` gives for the whole survey (``positions_table=False``); its
        ``table`` and ``stations`` empty. The notices in the same order."""
        from icgo.artifacts.format import domain_notices

        keys, notices, doubts = self.keys or set(), [], {}
        if "b_corr" in keys and self.n >= 3:
            m = self.moments
            line = field_doubt_line(model, (m["b_raw"].std() / max(m["b_raw"].mean, 1e-300), m["dip_raw"].std()),
                                    (m["b_corr"].std() / max(m["b_corr"].mean, 1e-300), m["dip_corr"].std()))
            if line:
                doubts["other_device"] = line
                notices.append(line)
        notices += [f"outside the training domain: {n}" for n in domain_notices(model.domain, self.domain)]
        qc = self.qc if self.all_qc else None
        if qc is None:
            notices.append(NO_REFERENCE_NOTICE if field is None else NO_SENSORS_NOTICE)
        for col, t in (("azimuth_deg", "a_true"), ("inclination_deg", "i_true")):
            if t in keys:
                line = self._radians_doubt(col)
                if line:
                    doubts["reference_units"] = line
                    notices.append(line)
                    break
        metrics = None
        if "a_true" in keys:
            metrics = {"compensated": self._metrics("a_comp")}
            if "a_raw" in keys:
                metrics["raw"] = self._metrics("a_raw")
        else:
            notices.append("no reference azimuth (azimuth_deg) in the survey: no error metrics, QC only")
        trajectory = None
        if "md" in keys:
            try:
                trajectory = self.positions.summary()
            except DataError as e:
                notices.append(f"no positions: {e}")
        return CorrectedSurvey(pd.DataFrame(), metrics, qc, notices, trajectory, doubts, {}, self.domain)

    def verdict(self, res: CorrectedSurvey, model, bands, *, out_csv: str, model_path: str, survey_path: str,
                method: str | None = None, reference: dict | None = None):
        """:func:`icgo.survey.verdict.summary_verdict` of the whole survey from the sums: the interval's coverage
        from its count, the |B| and dip deviations' exact medians (given as one value each: the verdict's QC line
        takes their median)."""
        from icgo.survey.verdict import summary_verdict

        keys = self.keys or set()
        interval = self.interval if "interval" in keys else None
        covered = self.sums["covered"] / self.n if interval is not None and "a_true" in keys else None
        med = {name: (np.array([self.columns[name].median()]) if name in keys and self.n else None)
               for name in ("db_nT", "ddip_deg")}
        return summary_verdict(res, model, bands, interval=interval, covered=covered, db_nT=med["db_nT"],
                               ddip_deg=med["ddip_deg"], out_csv=out_csv, model_path=model_path,
                               survey_path=survey_path, method=method, reference=reference)
