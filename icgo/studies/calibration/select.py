"""Which calibration to apply, and how accurate it is: one rule on held-out splits, its accuracy nested.

**The rule** (:func:`choose`), on the held-out scores of one set of splits (the peer's metric, deg):

* candidates: the methods saved as models with a sound fit (:mod:`icgo.models.cal_sanity`) in every split
  and no fit inconsistent with the site (:mod:`icgo.models.cal_site`; only when the site is known);
* the baseline is :data:`BASELINE` (``twelve+axis``, the 12-parameter least squares): another candidate is
  preferred only where it **beats the baseline by more than the standard error** of their paired difference
  over the held-out splits (mean of ``score_baseline - score_method`` above its standard error); among the
  baseline and the methods that do, the lowest mean held-out score is chosen. A method fitted with more freedom
  (the joint fit's accelerometer, the RELM's correction, MISMA's search) has to show on held-out shots that
  the freedom generalises;
* a margin is a margin only when it is at least :data:`MIN_MARGIN_DEG` as well (a RELM whose correction the
  regularisation shrinks to nothing scores within 1e-6 deg of the baseline, with a standard error smaller
  still: that is no win), and only over two or more held-out splits (one split has no standard error);
* without a held-out split (one roll too short to halve) nothing can show that, and the baseline is chosen;
  without a sound baseline, the lowest mean among the candidates. "A clear winner" obeys the same two
  conditions against the runner-up.

**Its accuracy** (:func:`nested_accuracy`): the rule chooses on held-out splits, so the mean held-out score of
its choice is optimistic (the winner's curse). The accuracy reported is nested: for each outer held-out
split, the rule is applied to splits made inside that split's training shots only (inner splits, the same
leave-one-roll-out or halves), and the method it chooses there is scored on the outer split's held-out shots;
the mean over the outer splits is the estimate of what the rule delivers on shots it did not see.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

#: The method every other one has to beat (module doc).
BASELINE = "twelve+axis"
#: The smallest margin (deg) that counts as one method beating another: a tenth of the 0.1 deg pointing accuracy
#: of the best survey tools (a smaller difference has no use in the field). Set from that, not from a recording.
MIN_MARGIN_DEG = 0.01


def beats(d) -> tuple[float, float] | None:
    """``(mean, standard error)`` of the paired differences ``d`` (deg, the loser's score minus the winner's over
    the held-out splits) when they make a win: two or more splits, the mean above its standard error and at least
    :data:`MIN_MARGIN_DEG`; else None."""
    se = _se(d)
    m = float(np.mean(d)) if np.size(d) else 0.0
    return (m, se) if se is not None and m > se and m >= MIN_MARGIN_DEG else None


class Choice(NamedTuple):
    """What :func:`choose` decided.

    Attributes:
        method: the chosen method, or None when no candidate is sound.
        mean_deg: its mean score over the splits it was chosen on (optimistic: module doc), or None.
        spread_deg: the standard error of that mean (None with fewer than two splits).
        runner_up: the candidate with the next lowest mean, or None.
        clear: the chosen method's margin over the runner-up exceeds the standard error of their paired
            difference.
        why: one sentence: the rule's decision in words (or why nothing was chosen).
        candidates: {method: mean deg} of the candidates; excluded: {method: reason} of the others.
    """

    method: str | None
    mean_deg: float | None
    spread_deg: float | None
    runner_up: str | None
    clear: bool
    why: str
    candidates: dict
    excluded: dict


def _se(x) -> float | None:
    x = np.asarray(x, np.float64)
    return float(np.std(x, ddof=1) / np.sqrt(x.size)) if x.size > 1 else None


def choose(scores: dict, excluded: dict, methods, held: bool) -> Choice:
    """The rule of the module doc.

    Args:
        scores: method -> (S,) scores over the splits (deg; NaN where that split's fit is degenerate).
        excluded: method -> reason, methods ruled out before the scores (e.g. inconsistent with the site).
        methods: the methods that may be chosen, in table order.
        held: whether the splits are held-out ones (False: in-sample only, the baseline is chosen).
    """
    out = dict(excluded)
    sound = {}
    for m in methods:
        if m not in scores or m in out:
            continue
        s = np.asarray(scores[m], np.float64)
        if s.size == 0 or not np.all(np.isfinite(s)):
            out[m] = "a degenerate fit (cal_sanity) in some split"
            continue
        sound[m] = s
    means = {m: float(np.mean(s)) for m, s in sound.items()}
    if not sound:
        why = ("no sound calibration: every method has a degenerate fit or one inconsistent with the site ("
               + "; ".join(f"{m}: {r}" for m, r in out.items()) + ")")
        return Choice(None, None, None, None, False, why, {}, out)
    ranked = sorted(sound, key=lambda m: (means[m], list(methods).index(m)))
    if not held:
        pick = BASELINE if BASELINE in sound else ranked[0]
        why = (f"no held-out split: nothing shows that more freedom than {BASELINE} generalises, so "
               + (f"{BASELINE} (the baseline)" if pick == BASELINE else f"{pick} ({BASELINE} is not sound here)"))
    elif BASELINE in sound:
        beat = {}
        for m in ranked:
            if m == BASELINE:
                continue
            b = beats(sound[BASELINE] - sound[m])
            if b is not None:
                beat[m] = b
        contenders = [m for m in ranked if m == BASELINE or m in beat]
        pick = contenders[0]
        if pick == BASELINE:
            why = (f"{BASELINE}, the baseline: no other sound method beats it by more than the standard error of "
                   f"their paired difference over the held-out splits and by {MIN_MARGIN_DEG:g} deg or more")
        else:
            why = (f"{pick} beats {BASELINE} by {beat[pick][0]:.3f} deg, more than the standard error of their "
                   f"paired difference ({beat[pick][1]:.3f}), and has the lowest mean held-out score among the "
                   "methods that do")
    else:
        pick = ranked[0]
        why = f"{pick}: the lowest mean held-out score ({BASELINE} is not sound here, so nothing is gated)"
    runner = next((m for m in ranked if m != pick), None)
    clear = False
    if runner is not None and held:
        clear = beats(sound[runner] - sound[pick]) is not None
    return Choice(pick, means[pick], _se(sound[pick]) if held else None, runner, clear, why, means, out)


class Nested(NamedTuple):
    """:func:`nested_accuracy`.

    Attributes:
        mean_deg: mean over the outer splits of the outer score of the method chosen inside each (None when no
            outer split had a choice). spread_deg: its standard error over those splits (None below two).
        per_split: [{"split", "chosen", "score_deg", "why"}] one per outer held-out split.
    """

    mean_deg: float | None
    spread_deg: float | None
    per_split: list


def nested_accuracy(outer: dict, inner: dict) -> Nested:
    """The rule's accuracy on shots it did not see (module doc).

    Args:
        outer: outer split label -> {method: outer held-out score deg (NaN when degenerate)}.
        inner: outer split label -> :class:`Choice` made on that split's inner splits.
    """
    rows, scores = [], []
    for split, by_method in outer.items():
        c = inner[split]
        s = None if c.method is None else by_method.get(c.method)
        s = None if s is None or not np.isfinite(s) else float(s)
        rows.append({"split": split, "chosen": c.method, "score_deg": s, "why": c.why})
        if s is not None:
            scores.append(s)
    if not scores:
        return Nested(None, None, rows)
    return Nested(float(np.mean(scores)), _se(scores), rows)


def model_accuracy(df, recording: str, method: str) -> dict | None:
    """The expected accuracy of one method's in-sample calibration, as its model carries it
    (:data:`icgo.artifacts.calibration.ACCURACY_KEYS`): the mean held-out score (the peer's metric, deg) of its sound
    fits over the held-out splits with its standard error, or, without a held-out split, its in-sample score
    (optimistic, and named so); None when no fit of it was sound."""
    from icgo.studies.calibration.study import outer_rows

    g = outer_rows(df[(df["recording"] == recording) & (df["method"] == method)])
    held = g[g["split"] != "in-sample"]
    use = held if len(held) else g[g["split"] == "in-sample"]
    s = use["score_deg"].to_numpy(np.float64)
    ok = s[np.isfinite(s)]
    if not ok.size:
        return None
    if len(held):
        what = (f"held-out pointing spread of {method} (the peer's accuracy metric): mean over {ok.size} held-out "
                f"split(s), each fitted without the shots it is scored on"
                + (f"; {s.size - ok.size} split(s) degenerate, left out" if ok.size < s.size else ""))
    else:
        what = (f"in-sample pointing spread of {method} (no held-out split: one roll too short to halve; an "
                "in-sample score is optimistic)")
    return {"deg": float(ok.mean()), "spread_deg": _se(ok), "what": what}


def recommend(df, recording: str) -> dict:
    """The calibration to apply for one recording, why, and its nested accuracy (the module doc), from
    :func:`icgo.studies.calibration.study.evaluate`'s table.

    Returns:
        ``{"model", "method", "criterion", "held_out_deg", "spread_deg", "clear_winner", "runner_up",
        "accuracy_deg", "accuracy_spread_deg", "accuracy_splits", "refused", "sentence"}``: ``model`` the file
        name relative to the run directory (``models/<label>.json``), ``held_out_deg`` / ``spread_deg`` the
        chosen method's mean held-out score and its standard error on the splits it was chosen on
        (optimistic), ``accuracy_deg`` / ``accuracy_spread_deg`` the nested estimate and its standard error
        (None without a held-out split), ``accuracy_splits`` one entry per outer held-out split (the method
        chosen inside it and its score there), ``refused`` why nothing is recommended (``model`` and
        ``method`` None then) or None, ``sentence`` the report's line.
    """
    from icgo.studies.calibration.study import METHODS, model_label, outer_rows

    g = df[(df["recording"] == recording) & df["method"].isin(METHODS)]
    outer = outer_rows(g)
    held = outer[outer["split"] != "in-sample"]
    use = held if len(held) else outer[outer["split"] == "in-sample"]

    def flagged(rows):
        bad = rows[rows["site_flag"].astype(bool)]
        return {m: f"inconsistent with the site ({r})" for m, r in zip(bad["method"], bad["site_reason"])}

    choice = choose({m: use.loc[use["method"] == m, "score_deg"].to_numpy(np.float64) for m in METHODS},
                    flagged(outer), METHODS, held=bool(len(held)))
    outer_scores, inner = {}, {}
    for split in held["split"].unique():
        h = held[held["split"] == split]
        outer_scores[split] = dict(zip(h["method"], h["score_deg"].to_numpy(np.float64)))
        rows = g[g["outer"] == split]
        inner[split] = choose({m: rows.loc[rows["method"] == m, "score_deg"].to_numpy(np.float64) for m in METHODS},
                              flagged(rows), METHODS, held=bool(len(rows)))
    nested = nested_accuracy(outer_scores, inner)
    n = len(use) // max(1, use["method"].nunique())
    what = f"{n} held-out split(s)" if len(held) else "the in-sample split (no held-out split)"
    if choice.method is None:
        sentence = f"No calibration recommended: {choice.why}."
        return {"model": None, "method": None, "criterion": choice.why, "held_out_deg": None, "spread_deg": None,
                "clear_winner": False, "runner_up": None, "accuracy_deg": None, "accuracy_spread_deg": None,
                "accuracy_splits": nested.per_split, "refused": choice.why, "sentence": sentence}
    model = f"models/{model_label(recording, choice.method)}.json"
    own = model_accuracy(df, recording, choice.method)
    acc = "" if own is None or not len(held) else (
        f"expected accuracy {own['deg']:.3f}" + (f" +/- {own['spread_deg']:.3f}" if own["spread_deg"] is not None
                                                 else "")
        + " deg (its held-out score: the accuracy its model carries and apply prints); ")
    if nested.mean_deg is None:
        acc += "accuracy not estimated (no held-out split to score the rule on)"
    else:
        acc += (f"the rule's nested score {nested.mean_deg:.3f}"
                + (f" +/- {nested.spread_deg:.3f}" if nested.spread_deg is not None else "")
                + f" deg (nested: the rule applied inside each of {len(nested.per_split)} held-out split(s)' "
                "training shots, its choice scored on the held-out shots)")
    other = "" if choice.runner_up is None else (
        f", runner-up `{choice.runner_up}` {choice.candidates[choice.runner_up]:.3f} deg"
        if choice.candidates[choice.runner_up] >= choice.mean_deg else
        f"; `{choice.runner_up}` is lower there ({choice.candidates[choice.runner_up]:.3f} deg) but does not beat "
        f"{BASELINE} by more than the standard error")
    sentence = (f"Apply `{choice.method}` (`{model}`): {acc}. Chosen on {what} by the rule: {choice.why}; its mean "
                f"there {choice.mean_deg:.3f} deg (optimistic: chosen on those splits){other}.")
    return {"model": model, "method": choice.method, "criterion": choice.why, "held_out_deg": choice.mean_deg,
            "spread_deg": choice.spread_deg, "clear_winner": choice.clear, "runner_up": choice.runner_up,
            "accuracy_deg": nested.mean_deg, "accuracy_spread_deg": nested.spread_deg,
            "accuracy_splits": nested.per_split, "refused": None, "sentence": sentence}
