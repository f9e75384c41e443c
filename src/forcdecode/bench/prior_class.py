"""``forcdecode bench prior-class``: the rates of the prior-class rule (``learn.prior_class``) on simulated
families whose true K_eff is known.

Each family of a dataset.h5 (the merged workflow output, read only; or a results directory whose families
are not merged yet) gives the two observables the rule reads off its FORC image, the loop's remanence
m_r and the field H_n where the descending branch leaves saturation, and the sign of its true
K_eff = K_u − μ0 M_s²/2. Reported: the fraction of K_eff > 0 families the ``perpendicular`` rule refuses
(false refusals: a perpendicular-class model would turn away a film of its own class) and the fraction
of K_eff < 0 families it catches, with 90 % Clopper–Pearson intervals: for the shipped rule on every
family and on the halves of even sample id (where its H_n threshold was chosen) and odd sample id (not
used for that choice); for m_r alone; over sweeps of either threshold; and the K_eff > 0 families the
rule refuses (K_eff, Q = 2K_u/(μ0 M_s²), |D|/D_c).
"""

from __future__ import annotations

import json

import numpy as np
from ..core.errors import InputFileError
from ..core.io import read_config
from ..core.parameters import dmi_ratio, k_eff, prior_class, quality_factor
from ..dataset.merge import config_hash, physics_config
from ..learn.prior_class import (OBSERVABLE, PERPENDICULAR_MAX_EXIT_FIELD_T, PERPENDICULAR_MIN_REMANENCE,
                                 loop_remanence, saturation_exit_field)

SWEEP = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9)
"""Thresholds of m_r the bench reports beside the shipped one (H_n threshold kept)."""

EXIT_SWEEP = (None, 0.0, 0.05, 0.1, 0.125, 0.15, 0.2, 0.3)
"""Thresholds of H_n (T) the bench reports (m_r threshold kept); None: m_r alone."""


def _clopper_pearson(k: int, n: int, level: float = 0.9) -> list:
    from scipy.stats import beta

    if n == 0:
        return [float("nan"), float("nan")]
    a = (1 - level) / 2
    low = 0.0 if k == 0 else float(beta.ppf(a, k, n - k + 1))
    high = 1.0 if k == n else float(beta.ppf(1 - a, k + 1, n - k))
    return [low, high]


def family_observables(images, B_max_T: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """(m_r, H_n in T) of each FORC image (``learn.prior_class.loop_remanence``, ``saturation_exit_field``)."""

    return (np.array([loop_remanence(image) for image in images]),
            np.array([saturation_exit_field(image, B_max_T) for image in images]))


def _run_directory(results) -> tuple:
    """(sample_id, parameters table rows, images, config) of the family files of a workflow results
    directory not merged yet (``params/*.parquet``, ``families/chunk_*.h5``, ``config.json``)."""
    from pathlib import Path

    import h5py
    import pandas as pd

    results = Path(results)
    params = sorted(results.glob("params/*.parquet"))
    if not params:
        raise InputFileError(f"{results}: no params/*.parquet (a workflow results directory)")
    table = pd.concat([pd.read_parquet(p) for p in params], ignore_index=True).set_index("sample_id")
    ids, images = [], []
    for path in sorted(results.glob("families/chunk_*.h5")):
        with h5py.File(path, "r") as h5:
            status = h5["status"].asstr()[:]
            for k, sample_id in enumerate(h5["sample_id"][:]):
                if status[k] == "ok":
                    ids.append(int(sample_id))
                    images.append(h5["images"][k])
    return np.array(ids), table.loc[ids], np.array(images), read_config(results / "config.json")


def read_families(dataset) -> dict:
    """sample_id, m_r, H_n, K_eff, Q, |D|/D_c, M_s and K_u of every family of ``dataset``: a dataset.h5 or
    a workflow results directory whose families are not merged yet (both opened read-only)."""
    from pathlib import Path

    import h5py

    if Path(dataset).is_dir():
        sample_id, table, images, cfg = _run_directory(dataset)
        values = {k: table[k].to_numpy(float) for k in ("K_u", "Ms", "A_ex", "D")}
        digest = config_hash(physics_config(cfg))
    else:
        try:
            h5 = h5py.File(dataset, "r")
        except OSError as error:
            raise InputFileError(f"cannot open dataset {dataset}: {error}") from None
        with h5:
            columns = list(h5["parameters"].attrs["columns"])
            parameters = h5["parameters"][:]
            sample_id = h5["sample_id"][:]
            images = h5["images"][:]
            cfg = json.loads(h5.attrs["config_json"])
            digest = str(h5.attrs["config_hash"])
        values = {k: parameters[:, columns.index(k)] for k in ("K_u", "Ms", "A_ex", "D")}

    B_max = float((cfg.get("field") or {}).get("B_max_T", 1.0))
    m_r, h_n = family_observables(images, B_max)
    return {"sample_id": np.asarray(sample_id), "m_r": m_r, "H_n_T": h_n, "K_eff": k_eff(values),
            "Q": quality_factor(values), "D_over_Dc": dmi_ratio(values), "Ms": values["Ms"], "K_u": values["K_u"],
            "prior_class": prior_class(cfg), "config_hash": digest, "B_max_T": B_max}


def rule_rates(refused, keff, **rule) -> dict:
    """Refusals (boolean per family) among the K_eff > 0 and the K_eff ≤ 0 families; ``rule`` is recorded."""
    refused, keff = np.asarray(refused, bool), np.asarray(keff, float)
    pos, neg = keff > 0, keff <= 0
    k_pos, n_pos = int(np.sum(refused & pos)), int(np.sum(pos))
    k_neg, n_neg = int(np.sum(refused & neg)), int(np.sum(neg))
    return {**rule, "n_keff_positive": n_pos, "n_keff_negative": n_neg,
            "refused_keff_positive": k_pos, "caught_keff_negative": k_neg,
            "false_refusal_rate": k_pos / n_pos if n_pos else float("nan"),
            "false_refusal_ci90": _clopper_pearson(k_pos, n_pos),
            "catch_rate": k_neg / n_neg if n_neg else float("nan"), "catch_ci90": _clopper_pearson(k_neg, n_neg)}


def _refused(m_r, h_n, min_remanence, max_exit_field):
    low = ~(np.asarray(m_r, float) >= min_remanence)
    return low if max_exit_field is None else low & (np.asarray(h_n, float) > max_exit_field)


def prior_class_bench(dataset, sweep=SWEEP, exit_sweep=EXIT_SWEEP) -> dict:
    """The rates of the shipped rule (every family, even and odd sample ids), of m_r alone and of the
    sweeps on the families of ``dataset``; the refused K_eff > 0 families; quantiles of m_r and H_n in each
    regime; the K_eff < 0 families the rule lets through (their K_eff)."""

    fam = read_families(dataset)
    m_r, h_n, keff, ids = fam["m_r"], fam["H_n_T"], fam["K_eff"], fam["sample_id"]
    shipped = {"min_remanence": PERPENDICULAR_MIN_REMANENCE, "max_exit_field_T": PERPENDICULAR_MAX_EXIT_FIELD_T}
    refused = _refused(m_r, h_n, PERPENDICULAR_MIN_REMANENCE, PERPENDICULAR_MAX_EXIT_FIELD_T)
    even = ids % 2 == 0
    quantiles = (0.0, 0.05, 0.5, 0.95, 1.0)

    def q(values, mask):
        return {str(p): float(np.quantile(values[mask], p)) for p in quantiles} if mask.any() else {}

    return {"dataset": str(dataset), "config_hash": fam["config_hash"], "dataset_prior_class": fam["prior_class"],
            "B_max_T": fam["B_max_T"], "observable": OBSERVABLE, "n_families": int(len(m_r)),
            "rule": rule_rates(refused, keff, **shipped),
            "rule_even_ids": rule_rates(refused[even], keff[even], **shipped),
            "rule_odd_ids": rule_rates(refused[~even], keff[~even], **shipped),
            "remanence_only": rule_rates(_refused(m_r, h_n, PERPENDICULAR_MIN_REMANENCE, None), keff,
                                         min_remanence=PERPENDICULAR_MIN_REMANENCE, max_exit_field_T=None),
            "sweep_remanence": [rule_rates(_refused(m_r, h_n, t, PERPENDICULAR_MAX_EXIT_FIELD_T), keff, min_remanence=t,
                                           max_exit_field_T=PERPENDICULAR_MAX_EXIT_FIELD_T) for t in sweep],
            "sweep_exit_field": [{"even_ids": rule_rates(_refused(m_r[even], h_n[even], PERPENDICULAR_MIN_REMANENCE, h),
                                                         keff[even]),
                                  "odd_ids": rule_rates(_refused(m_r[~even], h_n[~even], PERPENDICULAR_MIN_REMANENCE, h),
                                                        keff[~even]),
                                  "max_exit_field_T": h} for h in exit_sweep],
            "quantiles": {"m_r": {"K_eff>0": q(m_r, keff > 0), "K_eff<0": q(m_r, keff <= 0)},
                          "H_n_T": {"K_eff>0": q(h_n, keff > 0), "K_eff<0": q(h_n, keff <= 0)}},
            "refused_keff_positive": [{"sample_id": int(ids[i]), "m_r": float(m_r[i]), "H_n_T": float(h_n[i]),
                                       "K_eff_kJ_m3": float(keff[i] / 1e3), "Q": float(fam["Q"][i]),
                                       "D_over_Dc": float(fam["D_over_Dc"][i]), "Ms_kA_m": float(fam["Ms"][i] / 1e3)}
                                      for i in np.flatnonzero(refused & (keff > 0))],
            "passed_keff_negative_K_eff_kJ_m3": sorted(float(keff[i] / 1e3) for i in np.flatnonzero(~refused & (keff <= 0)))}


def _rates_line(label: str, r: dict) -> str:
    return (f"  {label}: K_eff > 0 refused {r['refused_keff_positive']}/{r['n_keff_positive']} = "
            f"{100 * r['false_refusal_rate']:.1f} % (90 % CI {100 * r['false_refusal_ci90'][0]:.1f}-"
            f"{100 * r['false_refusal_ci90'][1]:.1f}); K_eff < 0 caught {r['caught_keff_negative']}/{r['n_keff_negative']} = "
            f"{100 * r['catch_rate']:.1f} % (90 % CI {100 * r['catch_ci90'][0]:.1f}-{100 * r['catch_ci90'][1]:.1f})")


def summary_lines(result: dict) -> list[str]:
    r = result["rule"]
    lines = [f"prior-class rule on {result['n_families']} families of {result['dataset']} (drawn from prior class "
             f"{result['dataset_prior_class']}): refuse when m_r < {r['min_remanence']:g} and H_n > "
             f"{r['max_exit_field_T']:g} T ({result['observable']})",
             _rates_line("every family", r), _rates_line("even sample ids (H_n threshold chosen here)", result["rule_even_ids"]),
             _rates_line("odd sample ids (not used for the choice)", result["rule_odd_ids"]),
             _rates_line("m_r alone", result["remanence_only"])]
    for name, unit in (("m_r", ""), ("H_n_T", " T")):
        lines.append(f"  {name} quantiles (0, 5, 50, 95, 100 %): " + "; ".join(
            f"{k}: " + ", ".join(f"{v:.3f}" for v in qs.values()) + unit for k, qs in result["quantiles"][name].items()))
    lines.append("  m_r threshold sweep (false refusals / catches): " + "; ".join(
        f"{s['min_remanence']:g}: {100 * s['false_refusal_rate']:.1f} % / {100 * s['catch_rate']:.1f} %"
        for s in result["sweep_remanence"]))
    lines.append("  H_n threshold sweep, even | odd ids (false refusals / catches): " + "; ".join(
        f"{'none' if s['max_exit_field_T'] is None else format(s['max_exit_field_T'], 'g')} T: "
        f"{100 * s['even_ids']['false_refusal_rate']:.1f} / {100 * s['even_ids']['catch_rate']:.1f} | "
        f"{100 * s['odd_ids']['false_refusal_rate']:.1f} / {100 * s['odd_ids']['catch_rate']:.1f}"
        for s in result["sweep_exit_field"]))
    for row in result["refused_keff_positive"]:
        lines.append(f"  refused K_eff > 0: sample {row['sample_id']}, m_r {row['m_r']:.3f}, H_n {row['H_n_T']:.3f} T, "
                     f"K_eff {row['K_eff_kJ_m3']:.1f} kJ/m3, Q {row['Q']:.3f}, |D|/D_c {row['D_over_Dc']:.2f}, "
                     f"M_s {row['Ms_kA_m']:.0f} kA/m")
    passed = result["passed_keff_negative_K_eff_kJ_m3"]
    if passed:
        lines.append(f"  K_eff < 0 let through: {len(passed)}, K_eff from {min(passed):.1f} to {max(passed):.1f} kJ/m3")
    return lines


__all__ = ["SWEEP", "EXIT_SWEEP", "family_observables", "read_families", "rule_rates", "prior_class_bench",
           "summary_lines"]
