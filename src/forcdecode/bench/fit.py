"""``forcdecode bench fit``'s scoring: refined vs amortized posterior on held-out families with known
truth, beside the trivial predictor that reads M_s alone (the draw prior's median given M_s), with a
paired bootstrap of each MAE difference and the binomial band of the coverage.

Rows are ``forcdecode fit`` results (``refine.finish_fit``) with ``truth_normalized`` added; all
errors in normalized units u ∈ [0, 1]."""

from __future__ import annotations

import numpy as np

from ..dataset.params import draw_prior_quantiles
from ..learn.scoring import binomial_band, bootstrap_interval


def _abs_errors(rows, summary_of, name) -> np.ndarray:
    return np.array([abs(summary_of(r)["parameters"][name]["median"] - r["truth_normalized"][name]) for r in rows])


def _inside(rows, summary_of, name) -> np.ndarray:
    return np.array([summary_of(r)["parameters"][name]["interval_90"][0] <= r["truth_normalized"][name]
                     <= summary_of(r)["parameters"][name]["interval_90"][1] for r in rows])


def _widths(rows, summary_of, name) -> np.ndarray:
    return np.array([np.subtract(*summary_of(r)["parameters"][name]["interval_90"][::-1]) for r in rows])


def families_to_resolve(differences, z: float = 1.645) -> int | None:
    """Families whose paired differences would give a two-sided 90 % interval of the mean (normal
    approximation) that just excludes 0, if the mean and spread stay as in ``differences``: ⌈(z s / |mean|)²⌉.
    None for a zero mean or fewer than two differences."""
    d = np.asarray(differences, float)
    if d.size < 2 or d.mean() == 0:
        return None
    return max(2, int(np.ceil((z * d.std(ddof=1) / abs(d.mean())) ** 2)))


def fit_summary(rows, budgets, bounds, rng: np.random.Generator, n_boot: int = 2000) -> dict:
    """Per parameter: MAE of the amortized median, of the refined median at each budget and of the
    M_s-only predictor (``mae_prior``); the refined − amortized MAE difference with its paired
    bootstrap 90 % interval, the number of families the refinement improved and the number of families a
    bench would need for that interval to exclude 0 if the mean difference is what was measured
    (``families_to_resolve``); 90 % coverage (amortized, refined) and its binomial band; the mean width
    of the 90 % intervals (normalized); where rows have image summaries, in how many the guard refused
    the image reading (``image_reading_refused``); mean ESS and wall time per budget; the 10/50/90 %
    points over families of the observation RMS over the floor (amortized draws, refined particles).
    Rows carrying ``variants`` (other readings of the same simulations) get each variant's MAE, paired
    interval and coverage under ``variants``."""
    names = rows[0]["names"]
    amortized = lambda r: r["amortized"]  # noqa: E731
    refined = {b: (lambda r, b=b: r["refined_by_budget"][str(b)]) for b in budgets}
    prior_err = {p: np.array([abs(float(draw_prior_quantiles(p, r["Ms"], [0.5], bounds)[0]) - r["truth_normalized"][p])
                              for r in rows]) for p in names}
    out = {"families": len(rows), "budgets": list(budgets),
           "mae_prior": {p: float(prior_err[p].mean()) for p in names},
           "mae_amortized": {p: float(_abs_errors(rows, amortized, p).mean()) for p in names},
           "mae_refined": {}, "mae_difference": {}, "mae_difference_interval_90": {}, "families_improved": {},
           "families_to_resolve": {},
           "coverage_amortized": {p: float(_inside(rows, amortized, p).mean()) for p in names},
           "coverage_refined": {}, "coverage_band_90": binomial_band(len(rows)),
           "width_90_amortized": {p: float(_widths(rows, amortized, p).mean()) for p in names}, "width_90_refined": {},
           "ess": {}, "wall_s": {}, "reached_full_likelihood": {}}
    for b in budgets:
        key = str(b)
        out["mae_refined"][key], out["mae_difference"][key] = {}, {}
        out["mae_difference_interval_90"][key], out["families_improved"][key] = {}, {}
        out["families_to_resolve"][key] = {}
        out["coverage_refined"][key] = {}
        out["width_90_refined"][key] = {p: float(_widths(rows, refined[b], p).mean()) for p in names}
        for p in names:
            before, after = _abs_errors(rows, amortized, p), _abs_errors(rows, refined[b], p)
            out["mae_refined"][key][p] = float(after.mean())
            out["mae_difference"][key][p] = float((after - before).mean())
            out["mae_difference_interval_90"][key][p] = bootstrap_interval(lambda d: float(d.mean()), [after - before],
                                                                           rng, n_boot)
            out["families_improved"][key][p] = int(np.sum(after < before))
            out["families_to_resolve"][key][p] = families_to_resolve(after - before)
            out["coverage_refined"][key][p] = float(_inside(rows, refined[b], p).mean())
        out["ess"][key] = float(np.mean([refined[b](r)["ess"] for r in rows]))
        out["wall_s"][key] = float(np.mean([refined[b](r)["wall_s"] for r in rows]))
        out["reached_full_likelihood"][key] = int(sum(not refined[b](r).get("tempered", False) for r in rows))
    variant_names = set.intersection(*(set(r.get("variants", {})) for r in rows))
    if variant_names:  # the same simulations read another way (e.g. the adjusted fit's proposal_as_prior)
        out["variants"] = {}
        for name in sorted(variant_names):
            as_rows = [{**r, "refined_by_budget": r["variants"][name]} for r in rows]
            scored = fit_summary([{k: v for k, v in r.items() if k != "variants"} for r in as_rows], budgets,
                                 bounds, rng, n_boot)
            out["variants"][name] = {k: scored[k] for k in ("mae_refined", "mae_difference_interval_90",
                                                            "families_improved", "coverage_refined",
                                                            "width_90_refined", "ess")}
    # the adjusted fit: how finely one simulated family's summary locates each parameter, for the network's
    # summaries and for those read from each family's own simulated images; where every row has it
    for key, field, of in (("summary_resolution_median", "summary_resolution", lambda s: s),
                           ("image_summary_resolution_median", "image_summaries", lambda s: s["resolution"])):
        present = [b for b in budgets if all(field in refined[b](r) for r in rows)]
        if present:
            out[key] = {str(b): {p: float(np.median([of(refined[b](r)[field])[p] for r in rows])) for p in names}
                        for b in present}
    refused = {str(b): [refined[b](r)["image_summaries"]["outside_simulations"] for r in rows
                        if "outside_simulations" in refined[b](r).get("image_summaries", {})] for b in budgets}
    if any(refused.values()):  # the adjusted fit's guard: families whose observed image summary lay outside
        out["image_reading_refused"] = {b: {"refused": int(sum(v)), "formed": len(v)} for b, v in refused.items()}
    checks = [r["observation_rms"] for r in rows if "observation_rms" in r]
    if checks:  # at the final budget of each family's run
        out["observation_rms_over_floor"] = {k: [float(v) for v in np.quantile([c[f"{k}_over_floor"] for c in checks],
                                                                              [0.1, 0.5, 0.9])]
                                             for k in ("amortized", "refined")}
    return out


CHOICE_NAMES = ("K_u", "A_ex", "D")
"""The parameters whose mean MAE chooses the adjusted fit's reading (``infer.refine.ADJUSTED_CHOICE``)."""


def reading_choice(rows, budget: int, rng: np.random.Generator, n_boot: int = 2000, names=CHOICE_NAMES) -> dict:
    """The rule that chooses the adjusted fit's answer, on these rows (validation families): per reading
    (the amortized posterior, the reported answer, each variant read off the same simulations) the mean
    over ``names`` of the MAE of its median at ``budget``, with paired bootstrap 90 % intervals of its
    difference to the amortized posterior and to the answer; ``best``: the reading with the lowest mean."""
    key = str(budget)
    names = [n for n in names if n in rows[0]["names"]]

    def errors(of) -> np.ndarray:  # (families,) mean over names of |median − truth|
        return np.mean([[abs(of(r)["parameters"][n]["median"] - r["truth_normalized"][n]) for n in names]
                        for r in rows], axis=1)

    readings = {"amortized": errors(lambda r: r["amortized"]),
                "answer": errors(lambda r: r["refined_by_budget"][key])}
    common = set.intersection(*(set(r.get("variants", {})) for r in rows)) if rows else set()
    for name in sorted(common):
        if all(key in r["variants"][name] for r in rows):
            readings[name] = errors(lambda r, name=name: r["variants"][name][key])
    table = {}
    for name, e in readings.items():
        table[name] = {"mean_mae": float(e.mean()),
                       "minus_amortized_ci90": bootstrap_interval(lambda d: float(d.mean()),
                                                                  [e - readings["amortized"]], rng, n_boot),
                       "minus_answer_ci90": bootstrap_interval(lambda d: float(d.mean()),
                                                               [e - readings["answer"]], rng, n_boot)}
    answers = {r["refined_by_budget"][key].get("reading") for r in rows}
    return {"budget": int(budget), "parameters": names, "families": len(rows), "readings": table,
            "answer_reading": sorted(a for a in answers if a), "best": min(table, key=lambda n: table[n]["mean_mae"])}


def choice_lines(choice: dict) -> list[str]:
    """The reading-choice table, lowest mean MAE first."""
    lines = [f"choice of the reading at {choice['budget']} simulations on {choice['families']} families: mean MAE of "
             f"{', '.join(choice['parameters'])} (answer now: {', '.join(choice['answer_reading']) or '-'})"]
    for name, row in sorted(choice["readings"].items(), key=lambda kv: kv[1]["mean_mae"]):
        a, b = row["minus_amortized_ci90"], row["minus_answer_ci90"]
        lines.append(f"  {name:28s} {row['mean_mae']:.3f}   − amortized [{a[0]:+.3f}, {a[1]:+.3f}]   "
                     f"− answer [{b[0]:+.3f}, {b[1]:+.3f}]")
    return lines


def summary_lines(out: dict) -> list[str]:
    """The printed table: MAE per parameter (M_s-only, amortized, refined per budget with the paired
    90 % interval of the difference), then coverage, β = 1 counts and wall time."""
    budgets, names = out["budgets"], list(out["mae_amortized"])
    lines = [f"{'parameter':16s} {'M_s only':>9s} {'amortized':>10s} "
             + " ".join(f"{'refined ' + str(b):>12s} {'Δ 90 % interval':>17s}" for b in budgets)]
    for p in names:
        cells = []
        for b in budgets:
            lo, hi = out["mae_difference_interval_90"][str(b)][p]
            cells.append(f"{out['mae_refined'][str(b)][p]:12.3f} [{lo:+.3f}, {hi:+.3f}]")
        lines.append(f"{p:16s} {out['mae_prior'][p]:9.3f} {out['mae_amortized'][p]:10.3f} " + " ".join(cells))
    band = out["coverage_band_90"]
    for b in budgets:
        needed = out["families_to_resolve"][str(b)]
        lines.append(f"families for the Δ interval at {b} to exclude 0 if the effect is as measured (now "
                     f"{out['families']}): " + ", ".join(f"{p} {'-' if needed[p] is None else needed[p]}" for p in names))
    lines.append(f"90 % coverage (band {band[0]:.2f}-{band[1]:.2f} at n = {out['families']}): amortized "
                 + ", ".join(f"{p} {out['coverage_amortized'][p]:.2f}" for p in names))
    for b in budgets:
        lines.append(f"  refined {b}: " + ", ".join(f"{p} {out['coverage_refined'][str(b)][p]:.2f}" for p in names)
                     + f"; beta = 1 in {out['reached_full_likelihood'][str(b)]} of {out['families']}")
    lines.append("mean 90 % width: amortized " + ", ".join(f"{p} {out['width_90_amortized'][p]:.3f}" for p in names))
    for b in budgets:
        lines.append(f"  refined {b}: " + ", ".join(f"{p} {out['width_90_refined'][str(b)][p]:.3f}" for p in names))
    if "observation_rms_over_floor" in out:
        a, r = out["observation_rms_over_floor"]["amortized"], out["observation_rms_over_floor"]["refined"]
        lines.append(f"observation RMS / floor (10/50/90 % over families): amortized draws {a[0]:.2f}/{a[1]:.2f}/{a[2]:.2f}, "
                     f"refined {r[0]:.2f}/{r[1]:.2f}/{r[2]:.2f}")
    for b, by_name in out.get("summary_resolution_median", {}).items():
        lines.append(f"summary resolution at {b} (median over families; above 1 the simulations cannot narrow "
                     "the parameter): " + ", ".join(f"{p} {v:.2g}" for p, v in by_name.items()))
    for b, by_name in out.get("image_summary_resolution_median", {}).items():
        lines.append(f"image summary resolution at {b} (median over families): "
                     + ", ".join(f"{p} {v:.2g}" for p, v in by_name.items()))
    for b, count in out.get("image_reading_refused", {}).items():
        lines.append(f"image reading at {b}: refused in {count['refused']} of the {count['formed']} families that have "
                     "image summaries (the observed summary outside the simulated cloud)")
    for name, variant in out.get("variants", {}).items():
        for b in budgets:
            lines.append(f"  variant {name}, {b}: MAE " + ", ".join(
                f"{p} {variant['mae_refined'][str(b)][p]:.3f}" for p in names) + "; 90 % coverage " + ", ".join(
                f"{p} {variant['coverage_refined'][str(b)][p]:.2f}" for p in names) + "; mean 90 % width " + ", ".join(
                f"{p} {variant['width_90_refined'][str(b)][p]:.3f}" for p in names))
    lines.append("mean wall time per family: " + ", ".join(f"{b} simulations {out['wall_s'][str(b)]:.0f} s"
                                                           for b in budgets))
    return lines


__all__ = ["families_to_resolve", "fit_summary", "summary_lines"]
