"""Alice + Bob + conformal intervals against the neural posterior, on the same test families.

Both are scored on the workflow's hash split (same seed → same test sample ids; checked when the
posterior's metrics list them). Per parameter, in normalized units u ∈ [0, 1]: MAE (Alice's point;
the posterior's median), 90 % coverage (Alice: Bob's conformal interval fitted on the calibration
split; posterior: central credible interval) with the binomial band of the test size, and the 90 %
width. "Narrower at equal coverage" is only claimed where both coverages sit inside the band.
"""

from __future__ import annotations

from ..core import io
from ..core.errors import DatasetError


def compare_estimators(alice_metrics_path, posterior_metrics_path, out=None) -> dict:
    """The comparison table (dict) from ``results/metrics.json`` and ``results/posterior/metrics.json``."""
    alice = io.read_json(alice_metrics_path, what="Alice's metrics", error=DatasetError)
    post = io.read_json(posterior_metrics_path, what="posterior metrics", error=DatasetError)
    if post.get("reported_on") != "test":
        raise DatasetError(f"{posterior_metrics_path}: the posterior was reported on {post.get('reported_on')!r}, not test")
    rows = {}
    band = post.get("coverage_binomial_band", {}).get("90")
    for name, p in post["per_parameter"].items():
        a = alice["parameters"].get(name)
        if a is None:
            continue
        if a.get("n_test") is not None and int(a["n_test"]) != int(post["n_test"]):
            raise DatasetError(f"{name}: Alice was tested on {a['n_test']} families, the posterior on {post['n_test']}: "
                               "not the same split")
        row = {"alice_mae": float(a["mae"]), "posterior_mae_median": float(p["mae_median"]),
               "posterior_mae_mean": float(p["mae_mean"]), "alice_coverage_90": float(a["coverage_90"]),
               "alice_width_90": float(a["width_90"]), "posterior_coverage_90": float(p["coverage_90"]),
               "posterior_width_90": float(p["width_90"]), "posterior_sbc_ks_p": float(p["sbc_ks_p"])}
        row["more_accurate"] = "posterior" if row["posterior_mae_median"] < row["alice_mae"] else "alice"
        inside = (lambda c: band is not None and band[0] <= c <= band[1])
        row["alice_calibrated"] = inside(row["alice_coverage_90"])
        row["posterior_calibrated"] = inside(row["posterior_coverage_90"])
        if row["alice_calibrated"] and row["posterior_calibrated"]:
            row["narrower_at_equal_coverage"] = ("posterior" if row["posterior_width_90"] < row["alice_width_90"]
                                                 else "alice")
        else:
            row["narrower_at_equal_coverage"] = None
        rows[name] = row
    result = {"n_test": int(post["n_test"]), "coverage_90_binomial_band": band, "units": "normalized u in [0, 1]",
              "parameters": rows}
    if out is not None:
        io.write_json(out, result)
    return result


def comparison_markdown(result: dict) -> list[str]:
    """The README table."""
    band = result["coverage_90_binomial_band"]
    lines = [f"Test families: {result['n_test']}; 90 % coverage binomial band "
             f"{band[0]:.2f}–{band[1]:.2f}" if band else f"Test families: {result['n_test']}", "",
             "| parameter | MAE Alice | MAE posterior (median) | cov. 90 % Alice+Bob+conformal (width) | "
             "cov. 90 % posterior (width) | SBC KS p | more accurate | narrower at equal coverage |",
             "|---|---|---|---|---|---|---|---|"]
    for name, r in result["parameters"].items():
        lines.append(f"| {name} | {r['alice_mae']:.3f} | {r['posterior_mae_median']:.3f} | "
                     f"{r['alice_coverage_90']:.2f} ({r['alice_width_90']:.3f}) | "
                     f"{r['posterior_coverage_90']:.2f} ({r['posterior_width_90']:.3f}) | {r['posterior_sbc_ks_p']:.2f} | "
                     f"{r['more_accurate']} | {r['narrower_at_equal_coverage'] or 'n/a (one outside the band)'} |")
    return lines


__all__ = ["compare_estimators", "comparison_markdown"]
