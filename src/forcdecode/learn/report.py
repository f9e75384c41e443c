"""Aggregate the per-parameter results into ``metrics.json`` and ``learning_curve.json`` and draw the
learning figures: Figure 3 of the seed paper (predicted vs target), Figure 5b–c (Alice's D against
Bob's error, counts and true mean error per bin), the learning curves with their power laws, the
error–retention curves and the uncertainty baselines (Bob, v̂, MC dropout, seed ensemble)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from ..core import io
from ..core.parameters import k_eff, prior_class
from ..core.streams import stream_rng
from .combinations import alice_combination_metrics
from .data import load_dataset
from .sealed import attach_sealed

FIGURE3_PANELS = ("A_ex", "N_pin", "K_u", "D")
LABELS = {"N_pin": r"$N_\mathrm{pin}$", "A_ex": r"$A_\mathrm{ex}$", "K_u": r"$K_u$", "D": r"$D$",
          "sigma_theta_deg": r"$\sigma_\theta$", "sigma_K": r"$\sigma_K$"}


SUMMARY_KEYS = ("mae", "mae_ci90", "pearson_r", "r_ci90", "skill", "skill_vs_prior", "skill_vs_prior_ci90",
                "skill_vs_ms_only", "skill_vs_ms_only_ci90", "coverage_90_ci90", "coverage_90_binomial_band",
                "baselines", "seeds", "normalisation", "uncertainty_baselines", "n_test", "baseline_mae",
                "mae_softmax_readout", "reported_on", "paper", "train_samples_per_s", "wall_s", "n_train",
                "n_validation", "n_calibration", "best_epoch", "epochs_run", "validation_identification")


def aggregate(metric_paths, out_path) -> dict:
    """metrics.json: per parameter the accuracy with its baselines and intervals, Bob's figures and the
    uncertainty baselines; ``image_adds_information``: the skill over the best trivial predictor has a
    90 % interval above 0, i.e. the intervals of the skill over the M_s-only baseline *and* over the
    prior (train median) both lie above 0 (beating an M_s-only k-NN that is worse than the prior is no
    evidence that the image carries the parameter)."""
    result = {"split": "hash of (seed, sample id); test reported only", "parameters": {}}
    for path in metric_paths:
        m = json.loads(Path(path).read_text())
        entry = {k: m[k] for k in SUMMARY_KEYS if k in m}
        bob = m["bob"]
        entry.update({k: v for k, v in bob.items() if k != "retention"})
        entry["retention_area"] = {k: bob["retention"][k] for k in ("area_bob", "area_oracle", "area_mc_dropout", "area_random")}
        lows = [(m.get(f"skill_vs_{b}_ci90") or [float("nan")])[0] for b in ("ms_only", "prior")]
        entry["image_adds_information"] = bool(all(np.isfinite(low) and low > 0 for low in lows))
        result["parameters"][m["parameter"]] = entry
    io.write_json(out_path, result)
    return result


def learning_curve_summary(metric_paths, out_path) -> dict:
    """learning_curve.json: per parameter the sizes, the test and validation MAE per seed, the trivial
    predictors' MAE on each split, the power-law fit (test) and the training-set size at which it would
    reach the paper's MAE (with its bootstrap interval)."""
    result = {"law": "MAE(N) = a N^-b", "parameters": {}}
    for path in metric_paths:
        m = json.loads(Path(path).read_text())
        curve = m["learning_curve"]
        fit = dict(curve["fit"])
        target = fit.pop("n_to_target", None)
        result["parameters"][m["parameter"]] = {
            "sizes": curve["sizes"], "mae": curve["mae"], "evaluated_on": curve["evaluated_on"], "fit": fit,
            "n_to_paper_mae": target,
            "baselines": m.get("baselines"),
            # scored on validation (choices are made there); absent in runs before this was recorded
            "mae_validation": curve.get("mae_validation"), "baselines_validation": curve.get("baselines_validation"),
        }
        result.setdefault("sizes", curve["sizes"])
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


def learning_curves(curves: dict, out_path) -> None:
    """Test MAE against the training-set size (mean ± spread over seeds), the fitted power law, its
    extrapolation, the M_s-only baseline (dotted) and the paper's MAE (dashed)."""
    plt = _plt()
    names = list(curves["parameters"])
    cols = min(3, max(1, len(names)))
    rows = int(np.ceil(len(names) / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(3.6 * cols, 3.0 * rows), squeeze=False)
    for ax in axes.flat[len(names):]:
        ax.axis("off")
    for ax, name in zip(axes.flat, names):
        c = curves["parameters"][name]
        sizes, mae = np.asarray(c["sizes"], float), np.asarray(c["mae"], float)
        ax.errorbar(sizes, np.nanmean(mae, axis=1), yerr=np.nanstd(mae, axis=1), fmt="o", color="tab:blue",
                    capsize=2, label="test MAE (seeds)")
        fit, target = c["fit"], c.get("n_to_paper_mae")
        if np.isfinite(fit["a"]) and np.isfinite(fit["b"]):
            right = sizes.max() * 4
            if target and np.isfinite(target["value"]):
                right = min(max(right, target["value"] * 1.5), 1e6)
            grid = np.geomspace(sizes.min(), right, 50)
            ax.plot(grid, fit["a"] * grid ** (-fit["b"]), color="tab:blue", lw=0.8,
                    label=f"a N$^{{-b}}$, b = {fit['b']:.2f}")
        if c.get("baselines"):
            ax.axhline(c["baselines"]["ms_only"], color="0.4", ls=":", label="M$_s$ only")
        if target:
            ax.axhline(target["target_mae"], color="tab:red", ls="--", lw=0.8, label="paper")
        ax.set(xscale="log", yscale="log", xlabel="training samples N", title=LABELS.get(name, name))
    axes[0][0].set_ylabel("test MAE (normalized)")
    axes[0][0].legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(out_path, dpi=140)
    plt.close(fig)


def uncertainty_figure(metrics: dict, out_path) -> None:
    """Per parameter: Spearman ρ (difficulty score vs true error) and the 90 % conformal width of each
    uncertainty method (Bob, v̂, MC dropout, seed ensemble) on the same test samples."""
    plt = _plt()
    names = list(metrics["parameters"])
    methods = ["bob", "vhat", "mc_dropout", "ensemble"]
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.6))
    x = np.arange(len(names))
    for k, method in enumerate(methods):
        rho = [metrics["parameters"][n].get("uncertainty_baselines", {}).get(method, {}).get("spearman", np.nan) for n in names]
        width = [metrics["parameters"][n].get("uncertainty_baselines", {}).get(method, {}).get("width_90", np.nan) for n in names]
        a.bar(x + (k - 1.5) * 0.2, rho, 0.2, label=method)
        b.bar(x + (k - 1.5) * 0.2, width, 0.2, label=method)
    for ax, title in ((a, "Spearman ρ with the true error (higher is better)"),
                      (b, "90 % conformal width at equal coverage (lower is better)")):
        ax.set_xticks(x, [LABELS.get(n, n) for n in names])
        ax.set_title(title, fontsize=9)
        ax.axhline(0, color="0.5", lw=0.5)
    a.legend(fontsize=7)
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


def _ci(pair) -> str:
    return f"[{pair[0]:.3f}, {pair[1]:.3f}]" if pair and np.all(np.isfinite(pair)) else "–"


def markdown(metrics: dict) -> str:
    """Human-readable tables: accuracy against the baselines and the paper, and the uncertainty methods."""
    lines = ["| parameter | n_test | MAE [90 % CI] | paper MAE | prior | M_s only | images shuffled | skill vs M_s only [90 % CI] "
             "| skill vs prior [90 % CI] | r [90 % CI] | seeds MAE (mean ± sd) | image adds information |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for name, m in metrics["parameters"].items():
        paper, base, seeds = m.get("paper") or {}, m.get("baselines", {}), m.get("seeds", {})
        lines.append(f"| {name} | {m['n_test']} | {m['mae']:.3f} {_ci(m.get('mae_ci90'))} | {paper.get('mae', '–')} | "
                     f"{base.get('prior', float('nan')):.3f} | {base.get('ms_only', float('nan')):.3f} | "
                     f"{base.get('images_shuffled', float('nan')):.3f} | {m.get('skill_vs_ms_only', float('nan')):.2f} "
                     f"{_ci(m.get('skill_vs_ms_only_ci90'))} | {m.get('skill_vs_prior', float('nan')):.2f} "
                     f"{_ci(m.get('skill_vs_prior_ci90'))} | {m['pearson_r']:.2f} {_ci(m.get('r_ci90'))} | "
                     f"{seeds.get('mean', float('nan')):.3f} ± {seeds.get('std', float('nan')):.3f} | "
                     f"{'yes' if m.get('image_adds_information') else 'no'} |")
    lines += ["", "| parameter | method | Spearman ρ | cov. 68 % (width) | cov. 90 % (width) | retention area (oracle / random) |",
              "|---|---|---|---|---|---|"]
    for name, m in metrics["parameters"].items():
        table = m.get("uncertainty_baselines", {})
        for method in ("bob", "vhat", "mc_dropout", "ensemble"):
            if method not in table:
                continue
            row = table[method]
            lines.append(f"| {name} | {method} | {row['spearman']:.2f} | {row['coverage_68']:.2f} ({row['width_68']:.3f}) | "
                         f"{row['coverage_90']:.2f} ({row['width_90']:.3f}) | {row['retention_area']:.3f} "
                         f"({table['oracle_retention_area']:.3f} / {table['random_retention_area']:.3f}) |")
    return "\n".join(lines) + "\n"


def alice_combinations(predictions: dict, dataset, seed: int = 0, n_boot: int = 2000, models=None) -> dict:
    """``combinations`` of metrics.json: the derived combinations (``core.parameters.COMBINATIONS``) of
    Alice's predicted parameters, plug-in (``learn.combinations.alice_combination_metrics``), on the test
    families; ``predictions``: name -> predictions frame, ``dataset``: the dataset.h5 they were made on
    (M_s and the bounds); ``models``: the directory of the ``<parameter>.pt`` files, for the images-shuffled
    baseline (each network on the test images permuted among the test families, M_s kept, as many
    permutations as Alice's per-parameter baseline); None: that baseline is left out."""
    data = load_dataset(dataset)
    position = {int(s): k for k, s in enumerate(data.sample_id)}
    names = list(predictions)
    frame = predictions[names[0]][["sample_id", "split"]]
    ids = frame["sample_id"].to_numpy()
    index = np.array([position[int(s)] for s in ids])
    prediction_u, target_u = {}, {}
    for name in names:
        other = predictions[name].set_index("sample_id").loc[ids]
        prediction_u[name], target_u[name] = other["prediction"].to_numpy(float), other["target"].to_numpy(float)
    shuffled_u = None
    if models is not None:
        # loads torch: imported only when this runs
        from .pipeline import N_SHUFFLES
        from .predictor import ParameterModel

        networks = {name: ParameterModel.load(Path(models) / f"{name}.pt") for name in names}
        test = np.flatnonzero(frame["split"].to_numpy() == "test")
        ms_si = data.values["Ms"][index]
        rng = stream_rng(seed, "baseline_shuffle", "combinations")
        shuffled_u = []
        for _ in range(N_SHUFFLES):
            permuted = test[rng.permutation(len(test))]
            one = {name: np.full(len(ids), np.nan) for name in names}
            for name, net in networks.items():
                one[name][test] = net.predict(data.images[index[permuted]], ms_si[test])["normalized"]
            shuffled_u.append(one)
    return alice_combination_metrics(prediction_u, target_u, data.ms_norm[index], data.bounds, frame["split"].to_numpy(),
                                     lambda *keys: stream_rng(seed, "bootstrap", "combinations", *keys), n_boot,
                                     shuffled_u=shuffled_u)


REGIMES = (("K_eff>0", "perpendicular films, K_eff = K_u - mu0 M_s^2/2 > 0"),
           ("K_eff<0", "in-plane films, K_eff <= 0"))
"""The two regimes of ``by_regime`` in metrics.json (the sign of the true K_eff)."""


def dataset_truth(dataset) -> tuple[dict, str]:
    """sample id -> true K_eff (J/m³) of the families of ``dataset`` (dataset.h5), and its prior class
    (``core.parameters.prior_class`` of the stored config; absent: paper). No images are read."""
    import h5py

    with h5py.File(dataset, "r") as h5:
        columns = list(h5["parameters"].attrs["columns"])
        parameters = h5["parameters"][:]
        ids = h5["sample_id"][:]
        cfg = json.loads(h5.attrs["config_json"])
    keff = k_eff({"K_u": parameters[:, columns.index("K_u")], "Ms": parameters[:, columns.index("Ms")]})
    return {int(s): float(k) for s, k in zip(ids, keff)}, prior_class(cfg)


def regime_metrics(predictions: dict, dataset) -> dict:
    """``by_regime`` of metrics.json: Alice's accuracy on the test families of each regime (``REGIMES``:
    the sign of the true K_eff), per parameter: the count, the MAE (normalized), the MAE of the two
    trivial predictors (the prior, the train split's median; M_s only, the frame's ``ms_only_prediction``)
    and the skills 1 − MAE / MAE(baseline) over each. Point figures without intervals (a regime may hold
    a handful of test families: read the counts). ``prior_class``: the class the dataset was drawn from."""
    keff, trained_on = dataset_truth(dataset)
    out = {"definition": "test families by the sign of the true K_eff = K_u - mu0 M_s^2/2; MAE of u (normalized); "
                         "skill = 1 - MAE / MAE(baseline), baselines: prior (train median), ms_only (M_s-only k-NN)",
           "prior_class": trained_on, "regimes": dict(REGIMES), "counts": {}, "parameters": {}}
    for name, frame in predictions.items():
        test = frame[frame["split"] == "test"]
        prior = float(np.median(frame.loc[frame["split"] == "train", "target"])) if (frame["split"] == "train").any() else float("nan")
        regime = np.array([keff.get(int(s), np.nan) for s in test["sample_id"]])
        entry = {}
        for label, where in (("K_eff>0", regime > 0), ("K_eff<0", regime <= 0)):
            part = test[where]
            n = int(len(part))
            out["counts"].setdefault(label, n)
            if n == 0:
                entry[label] = {"n": 0, "mae": None, "mae_prior": None, "mae_ms_only": None,
                                "skill_vs_prior": None, "skill_vs_ms_only": None}
                continue
            target = part["target"].to_numpy(float)
            mae = float(np.mean(np.abs(part["prediction"].to_numpy(float) - target)))
            mae_prior = float(np.mean(np.abs(prior - target)))
            mae_ms = (float(np.mean(np.abs(part["ms_only_prediction"].to_numpy(float) - target)))
                      if "ms_only_prediction" in part else float("nan"))
            entry[label] = {"n": n, "mae": mae, "mae_prior": mae_prior, "mae_ms_only": mae_ms,
                            "skill_vs_prior": 1.0 - mae / mae_prior if mae_prior > 0 else None,
                            "skill_vs_ms_only": 1.0 - mae / mae_ms if mae_ms > 0 else None}
        out["parameters"][name] = entry
    return out


def regime_markdown(by_regime: dict) -> str:
    """The per-regime table of metrics.md."""
    counts = by_regime["counts"]
    lines = ["", f"## By regime (test split; dataset prior class: {by_regime['prior_class']})", "",
             f"Counts: K_eff > 0: {counts.get('K_eff>0', 0)}, K_eff < 0: {counts.get('K_eff<0', 0)}.", "",
             "| parameter | regime | n | MAE | skill vs prior | skill vs M_s only |", "|---|---|---|---|---|---|"]

    def f(v):
        return "—" if v is None or not np.isfinite(v) else f"{v:.3f}"

    for name, entry in by_regime["parameters"].items():
        for label in ("K_eff>0", "K_eff<0"):
            e = entry[label]
            lines.append(f"| {name} | {label} | {e['n']} | {f(e['mae'])} | {f(e['skill_vs_prior'])} | "
                         f"{f(e['skill_vs_ms_only'])} |")
    return "\n".join(lines) + "\n"


@dataclass(frozen=True)
class TrainingDataset:
    """The dataset Alice was trained on, for the figures that need it: ``path`` (its dataset.h5),
    ``seed`` (the config seed: root of the combinations' bootstrap stream), ``n_boot`` (bootstrap
    resamples behind each 90 % interval) and ``models`` (the directory of the ``<parameter>.pt`` files,
    for the images-shuffled baseline; None: without it)."""

    path: object
    seed: int = 0
    n_boot: int = 2000
    models: object = None


def evaluate(metric_paths, prediction_paths, out_metrics, figure_dir, out_learning_curve=None,
             dataset: TrainingDataset | None = None, sealed: dict | None = None) -> dict:
    """metrics.json, learning_curve.json and the figures; with ``dataset`` (the dataset Alice was
    trained on) metrics.json also holds the derived combinations of Alice's predictions (with
    ``dataset.models``, the directory of the model files, their images-shuffled baseline too), the figures
    per regime of the true K_eff (``by_regime``, :func:`regime_metrics`) and the dataset's ``prior_class``;
    with ``sealed`` (the frozen networks' figures on the sealed set, ``learn.sealed``) they sit beside the
    test split's as ``sealed``."""
    figure_dir = Path(figure_dir)
    figure_dir.mkdir(parents=True, exist_ok=True)
    metrics = aggregate(metric_paths, out_metrics)
    curves = learning_curve_summary(metric_paths, out_learning_curve or Path(out_metrics).with_name("learning_curve.json"))
    predictions = {}
    for path in prediction_paths:
        name = Path(path).stem.replace("_predictions", "")
        predictions[name] = pd.read_parquet(path)
    if dataset is not None:
        metrics["combinations"] = alice_combinations(predictions, dataset.path, dataset.seed, dataset.n_boot,
                                                     dataset.models)
        metrics["by_regime"] = regime_metrics(predictions, dataset.path)
        metrics["prior_class"] = metrics["by_regime"]["prior_class"]
    if sealed is not None:
        metrics = attach_sealed(metrics, sealed)
    if dataset is not None or sealed is not None:
        io.write_json(out_metrics, json.loads(json.dumps(metrics, default=float)))
    figure3(predictions, figure_dir / "figure3.png")
    name = "D" if "D" in predictions else next(iter(predictions))
    figure5bc(predictions[name], figure_dir / "figure5bc.png", name=name)
    learning_curves(curves, figure_dir / "learning_curve.png")
    retention_figure(metric_paths, figure_dir / "retention.png")
    uncertainty_figure(metrics, figure_dir / "uncertainty_baselines.png")
    with io.atomic_path(Path(out_metrics).with_suffix(".md")) as tmp:
        tmp.write_text("# Alice and Bob on the test split\n\n" + markdown(metrics)
                       + (regime_markdown(metrics["by_regime"]) if "by_regime" in metrics else ""))
    return metrics
