"""``forcdecode bench prior-class``: the rates of the prior-class rule (``learn.prior_class``) on simulated
families whose true K_eff is known.

Each family of a dataset.h5 (the merged workflow output, read only) gives the observable the rule reads,
the major loop's remanence m_r of its FORC image, and the sign of its true K_eff = K_u − μ0 M_s²/2.
Reported: the fraction of K_eff > 0 families the ``perpendicular`` rule refuses (false refusals: a
perpendicular-class model would turn away a film of its own class) and the fraction of K_eff < 0 families
it catches, with 90 % Clopper–Pearson intervals, at the shipped threshold and over a sweep of thresholds;
and the refused K_eff > 0 families themselves (their K_eff and Q = 2K_u/(μ0 M_s²)).
"""

from __future__ import annotations

import json

import numpy as np

SWEEP = (0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9)
"""Thresholds of m_r the bench reports beside the shipped one."""


def _clopper_pearson(k: int, n: int, level: float = 0.9) -> list:
    from scipy.stats import beta

    if n == 0:
        return [float("nan"), float("nan")]
    a = (1 - level) / 2
    low = 0.0 if k == 0 else float(beta.ppf(a, k, n - k + 1))
    high = 1.0 if k == n else float(beta.ppf(1 - a, k + 1, n - k))
    return [low, high]


def family_remanence(images) -> np.ndarray:
    """m_r of each FORC image (``learn.prior_class.loop_remanence``)."""
    from ..learn.prior_class import loop_remanence

    return np.array([loop_remanence(image) for image in images])


def _run_directory(results) -> tuple:
    """(sample_id, parameters table rows, images, config) of the family files of a workflow results
    directory not merged yet (``params/*.parquet``, ``families/chunk_*.h5``, ``config.json``)."""
    from pathlib import Path

    import h5py
    import pandas as pd

    from ..core.errors import InputFileError
    from ..core.io import read_config

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
    """sample_id, m_r, K_eff, Q, M_s and K_u of every family of ``dataset``: a dataset.h5 or a workflow
    results directory whose families are not merged yet (both opened read-only)."""
    from pathlib import Path

    import h5py

    from ..core.errors import InputFileError
    from ..core.parameters import k_eff, prior_class, quality_factor

    if Path(dataset).is_dir():
        from ..dataset.merge import config_hash, physics_config

        sample_id, table, images, cfg = _run_directory(dataset)
        values = {"K_u": table["K_u"].to_numpy(float), "Ms": table["Ms"].to_numpy(float)}
        return {"sample_id": sample_id, "m_r": family_remanence(images), "K_eff": k_eff(values),
                "Q": quality_factor(values), "Ms": values["Ms"], "K_u": values["K_u"], "prior_class": prior_class(cfg),
                "config_hash": config_hash(physics_config(cfg))}
    try:
        h5 = h5py.File(dataset, "r")
    except OSError as error:
        raise InputFileError(f"cannot open dataset {dataset}: {error}") from None
    with h5:
        columns = list(h5["parameters"].attrs["columns"])
        parameters = h5["parameters"][:]
        sample_id = h5["sample_id"][:]
        m_r = family_remanence(h5["images"][:])
        cfg = json.loads(h5.attrs["config_json"])
        config_hash = str(h5.attrs["config_hash"])
    values = {"K_u": parameters[:, columns.index("K_u")], "Ms": parameters[:, columns.index("Ms")]}
    return {"sample_id": sample_id, "m_r": m_r, "K_eff": k_eff(values), "Q": quality_factor(values),
            "Ms": values["Ms"], "K_u": values["K_u"], "prior_class": prior_class(cfg), "config_hash": config_hash}


def rule_rates(m_r, keff, threshold: float) -> dict:
    """Refusals of the rule m_r < ``threshold`` among the K_eff > 0 and the K_eff ≤ 0 families."""
    m_r, keff = np.asarray(m_r, float), np.asarray(keff, float)
    refused = ~(m_r >= threshold)
    pos, neg = keff > 0, keff <= 0
    k_pos, n_pos = int(np.sum(refused & pos)), int(np.sum(pos))
    k_neg, n_neg = int(np.sum(refused & neg)), int(np.sum(neg))
    return {"threshold": float(threshold), "n_keff_positive": n_pos, "n_keff_negative": n_neg,
            "refused_keff_positive": k_pos, "caught_keff_negative": k_neg,
            "false_refusal_rate": k_pos / n_pos if n_pos else float("nan"),
            "false_refusal_ci90": _clopper_pearson(k_pos, n_pos),
            "catch_rate": k_neg / n_neg if n_neg else float("nan"), "catch_ci90": _clopper_pearson(k_neg, n_neg)}


def prior_class_bench(dataset, sweep=SWEEP) -> dict:
    """The rates of the shipped rule and of the sweep on the families of ``dataset``, and the refused
    K_eff > 0 families; quantiles of m_r in each regime."""
    from ..learn.prior_class import OBSERVABLE, PERPENDICULAR_MIN_REMANENCE

    fam = read_families(dataset)
    m_r, keff = fam["m_r"], fam["K_eff"]
    shipped = rule_rates(m_r, keff, PERPENDICULAR_MIN_REMANENCE)
    refused = np.flatnonzero((keff > 0) & ~(m_r >= PERPENDICULAR_MIN_REMANENCE))
    quantiles = (0.0, 0.05, 0.5, 0.95, 1.0)

    def q(mask):
        return {str(p): float(np.quantile(m_r[mask], p)) for p in quantiles} if mask.any() else {}

    return {"dataset": str(dataset), "config_hash": fam["config_hash"], "dataset_prior_class": fam["prior_class"],
            "observable": OBSERVABLE, "n_families": int(len(m_r)), "rule": shipped,
            "sweep": [rule_rates(m_r, keff, t) for t in sweep],
            "m_r_quantiles": {"K_eff>0": q(keff > 0), "K_eff<0": q(keff <= 0)},
            "refused_keff_positive": [{"sample_id": int(fam["sample_id"][i]), "m_r": float(m_r[i]),
                                       "K_eff_kJ_m3": float(keff[i] / 1e3), "Q": float(fam["Q"][i]),
                                       "Ms_kA_m": float(fam["Ms"][i] / 1e3)} for i in refused],
            "largest_m_r_keff_negative": float(m_r[keff <= 0].max()) if (keff <= 0).any() else None}


def summary_lines(result: dict) -> list[str]:
    r = result["rule"]
    lines = [f"prior-class rule on {result['n_families']} families of {result['dataset']} "
             f"(drawn from prior class {result['dataset_prior_class']}): refuse when {result['observable']} "
             f"< {r['threshold']:g}",
             f"  K_eff > 0 refused (false refusals): {r['refused_keff_positive']}/{r['n_keff_positive']} = "
             f"{100 * r['false_refusal_rate']:.1f} % (90 % CI {100 * r['false_refusal_ci90'][0]:.1f}-"
             f"{100 * r['false_refusal_ci90'][1]:.1f} %)",
             f"  K_eff < 0 caught: {r['caught_keff_negative']}/{r['n_keff_negative']} = {100 * r['catch_rate']:.1f} % "
             f"(90 % CI {100 * r['catch_ci90'][0]:.1f}-{100 * r['catch_ci90'][1]:.1f} %)",
             "  m_r quantiles (0, 5, 50, 95, 100 %): "
             + "; ".join(f"{k}: " + ", ".join(f"{v:.3f}" for v in qs.values()) for k, qs in result["m_r_quantiles"].items()),
             "  sweep (threshold: false refusals / catches): "
             + "; ".join(f"{s['threshold']:g}: {100 * s['false_refusal_rate']:.1f} % / {100 * s['catch_rate']:.1f} %"
                         for s in result["sweep"])]
    for row in result["refused_keff_positive"]:
        lines.append(f"  refused K_eff > 0: sample {row['sample_id']}, m_r {row['m_r']:.3f}, K_eff "
                     f"{row['K_eff_kJ_m3']:.1f} kJ/m3, Q {row['Q']:.3f}, M_s {row['Ms_kA_m']:.0f} kA/m")
    return lines


__all__ = ["SWEEP", "family_remanence", "read_families", "rule_rates", "prior_class_bench", "summary_lines"]
