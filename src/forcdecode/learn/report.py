"""Aggregate the per-parameter results into ``metrics.json`` and draw the learning figures:
Figure 3 of the seed paper (predicted vs target), Figure 5b–c (Alice's D against Bob's error, counts
and true mean error per bin), the learning curves and the error–retention curves."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from ..dataset import io

FIGURE3_PANELS = ("A_ex", "N_pin", "K_u", "D")
LABELS = {"N_pin": r"$N_\mathrm{pin}$", "A_ex": r"$A_\mathrm{ex}$", "K_u": r"$K_u$", "D": r"$D$",
          "sigma_theta_deg": r"$\sigma_\theta$", "sigma_K": r"$\sigma_K$"}


def aggregate(metric_paths, out_path) -> dict:
    """metrics.json: per parameter ``mae``, ``pearson_r``, ``skill``, ``n_test`` and Bob's figures."""
    result = {"parameters": {}}
    for path in metric_paths:
        m = json.loads(Path(path).read_text())
        entry = {k: m[k] for k in ("mae", "pearson_r", "skill", "n_test", "baseline_mae", "mae_softmax_readout",
                                   "reported_on", "paper", "train_samples_per_s", "wall_s", "learning_curve",
                                   "n_train", "n_validation", "n_calibration", "best_epoch", "epochs_run")}
        bob = m["bob"]
        entry.update({k: v for k, v in bob.items() if k != "retention"})
        entry["retention_area"] = {k: bob["retention"][k] for k in ("area_bob", "area_oracle", "area_mc_dropout", "area_random")}
        result["parameters"][m["parameter"]] = entry
    io.write_json(out_path, result)
    return result


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def figure3(predictions: dict, out_path) -> None:
    """Predicted vs target on the test split, four panels, ±0.15 lines, 20 % opacity."""
    plt = _plt()
    names = [n for n in FIGURE3_PANELS if n in predictions]
    fig, axes = plt.subplots(1, max(1, len(names)), figsize=(3.3 * max(1, len(names)), 3.4), squeeze=False)
    for ax, name in zip(axes[0], names):
        frame = predictions[name]
        test = frame[frame["split"] == "test"]
        ax.scatter(test["target"], test["prediction"], s=14, alpha=0.2, color="tab:blue", edgecolors="none")
        x = np.linspace(0, 1, 2)
        ax.plot(x, x, color="0.3", lw=0.8)
        ax.plot(x, x + 0.15, color="red", lw=0.8)
        ax.plot(x, x - 0.15, color="red", lw=0.8)
        mae = np.mean(np.abs(test["prediction"] - test["target"]))
        ax.set(xlim=(0, 1), ylim=(0, 1), xlabel=f"target {LABELS[name]} (normalized)",
               ylabel=f"predicted {LABELS[name]}", title=f"{LABELS[name]}: MAE {mae:.3f}, n={len(test)}")
        ax.set_aspect("equal")
    fig.tight_layout()
    fig.savefig(out_path, dpi=140)
    plt.close(fig)


def figure5bc(frame: pd.DataFrame, out_path, name: str = "D", bins: int = 15, min_count: int = 5) -> None:
    """(b) counts of (Alice's prediction, Bob's error) in 15×15 bins, bins with < 5 points masked;
    (c) the same bins colored by Alice's true mean error. All evaluation samples (not train)."""
    plt = _plt()
    data = frame[frame["split"] != "train"]
    x, y, err = data["prediction"].to_numpy(), data["bob_error"].to_numpy(), data["abs_error"].to_numpy()
    x_edges = np.linspace(0, 1, bins + 1)
    y_edges = np.linspace(0, max(float(np.max(y)) if y.size else 1.0, 1e-3) * 1.0001, bins + 1)
    counts, _, _ = np.histogram2d(x, y, [x_edges, y_edges])
    sums, _, _ = np.histogram2d(x, y, [x_edges, y_edges], weights=err)
    mask = counts < min_count
    mean_error = np.where(mask, np.nan, sums / np.maximum(counts, 1))
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    im = a.pcolormesh(x_edges, y_edges, np.ma.masked_where(mask, counts).T, cmap="jet")
    fig.colorbar(im, ax=a, label="count")
    a.set(xlabel=f"Alice's {LABELS[name]} (normalized)", ylabel=r"Bob's error $\langle|\epsilon|\rangle$",
          title=f"(b) counts; bins < {min_count} masked")
    im = b.pcolormesh(x_edges, y_edges, np.ma.masked_invalid(mean_error).T, cmap="jet")
    fig.colorbar(im, ax=b, label="Alice's true mean |error|")
    b.set(xlabel=f"Alice's {LABELS[name]} (normalized)", ylabel=r"Bob's error $\langle|\epsilon|\rangle$",
          title="(c) true mean error per bin")
    fig.tight_layout()
    fig.savefig(out_path, dpi=140)
    plt.close(fig)


def learning_curves(metrics: dict, out_path) -> None:
    plt = _plt()
    fig, ax = plt.subplots(figsize=(5, 3.8))
    for name, m in metrics["parameters"].items():
        curve = m["learning_curve"]
        ax.plot([c["n_train"] for c in curve], [c["test_mae"] for c in curve], "o-", label=LABELS.get(name, name))
    ax.set(xlabel="training samples", ylabel="test MAE (normalized)", title="learning curves")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out_path, dpi=140)
    plt.close(fig)


def retention_figure(metric_paths, out_path) -> None:
    plt = _plt()
    items = [json.loads(Path(p).read_text()) for p in metric_paths]
    fig, axes = plt.subplots(1, len(items), figsize=(3.2 * len(items), 3.2), squeeze=False)
    for ax, m in zip(axes[0], items):
        r = m["bob"]["retention"]
        ax.plot(r["fractions"], r["oracle"], color="k", label="oracle")
        ax.plot(r["fractions"], r["bob"], color="tab:red", label="Bob")
        ax.plot(r["fractions"], r["mc_dropout"], color="tab:blue", ls="--", label="MC dropout")
        ax.axhline(r["random"], color="0.6", ls=":", label="random")
        ax.set(xlabel="fraction retained", title=LABELS.get(m["parameter"], m["parameter"]))
    axes[0][0].set_ylabel("mean |error| of retained")
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out_path, dpi=130)
    plt.close(fig)


def markdown(metrics: dict) -> str:
    """A human-readable table of the metrics (next to the paper's figures)."""
    lines = ["| parameter | n_test | MAE | paper MAE | r | paper r | skill | Bob ρ | MC ρ | cov. 68 % (width) | cov. 90 % (width) | MC cov. 68/90 % |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for name, m in metrics["parameters"].items():
        paper = m.get("paper") or {}
        lines.append(f"| {name} | {m['n_test']} | {m['mae']:.3f} | {paper.get('mae', '–')} | {m['pearson_r']:.2f} | "
                     f"{paper.get('pearson_r', '–')} | {m['skill']:.2f} | {m['bob_spearman']:.2f} | {m['mc_dropout_spearman']:.2f} | "
                     f"{m['coverage_68']:.2f} ({m['width_68']:.3f}) | {m['coverage_90']:.2f} ({m['width_90']:.3f}) | "
                     f"{m['mc_coverage_68']:.2f}/{m['mc_coverage_90']:.2f} |")
    return "\n".join(lines) + "\n"


def evaluate(metric_paths, prediction_paths, out_metrics, figure_dir) -> dict:
    figure_dir = Path(figure_dir)
    figure_dir.mkdir(parents=True, exist_ok=True)
    metrics = aggregate(metric_paths, out_metrics)
    predictions = {}
    for path in prediction_paths:
        name = Path(path).stem.replace("_predictions", "")
        predictions[name] = pd.read_parquet(path)
    figure3(predictions, figure_dir / "figure3.png")
    name = "D" if "D" in predictions else next(iter(predictions))
    figure5bc(predictions[name], figure_dir / "figure5bc.png", name=name)
    learning_curves(metrics, figure_dir / "learning_curve.png")
    retention_figure(metric_paths, figure_dir / "retention.png")
    with io.atomic_path(Path(out_metrics).with_suffix(".md")) as tmp:
        tmp.write_text("# Alice and Bob on the test split\n\n" + markdown(metrics))
    return metrics
