"""The closed loop on the simulated test set: F_sim(F_CNN(y)) against y.

For each test sample, the Hamiltonian predicted by the Alice networks (with the known M_s; σ_θ and
σ_K predicted too) is re-simulated with the dataset's protocol, and the observation-space error is
the RMS difference of ⟨m_z⟩ over every FORC point (H ≥ H_r). It is compared with Bob's predicted
errors (mean over the parameters) by Spearman's ρ, and Figure 4 of the seed paper draws ten
random test samples, input (red) vs re-simulated (dark).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from ..dataset.params import denormalize
from .resimulate import observation_error, resimulate


def predicted_hamiltonians(prediction_paths: dict, values: pd.DataFrame, bounds: dict) -> pd.DataFrame:
    """Per test sample: the predicted parameters (SI), the true M_s, Bob's mean normalized error."""
    frames = {name: pd.read_parquet(path).set_index("sample_id") for name, path in prediction_paths.items()}
    test_ids = None
    for frame in frames.values():
        ids = set(frame.index[frame["split"] == "test"])
        test_ids = ids if test_ids is None else test_ids & ids
    ids = sorted(test_ids or [])
    out = pd.DataFrame({"sample_id": ids}).set_index("sample_id")
    out["Ms"] = values.loc[ids, "Ms"].to_numpy()
    for name, frame in frames.items():
        out[name] = denormalize(name, frame.loc[ids, "prediction"].to_numpy(), bounds)
        out[f"{name}_bob_error"] = frame.loc[ids, "bob_error"].to_numpy()
        out[f"{name}_abs_error"] = frame.loc[ids, "abs_error"].to_numpy()
    out["bob_error_mean"] = out[[f"{n}_bob_error" for n in frames]].mean(axis=1)
    out["abs_error_mean"] = out[[f"{n}_abs_error" for n in frames]].mean(axis=1)
    if "N_pin" in out:
        out["N_pin"] = np.rint(out["N_pin"]).astype(int)
    return out.reset_index()


def closed_loop(cfg: dict, table: pd.DataFrame, curves_by_id: dict, defaults: dict, max_samples: int, seed: int,
                progress=None) -> tuple[pd.DataFrame, dict]:
    """Re-simulate up to ``max_samples`` test samples (a seeded random subset); returns the table with
    ``observation_rms`` and the re-simulated families by sample id."""
    rng = np.random.default_rng(seed + 5_000_005)
    chosen = table if len(table) <= max_samples else table.iloc[np.sort(rng.choice(len(table), max_samples, replace=False))]
    rows, families = [], {}
    for k, row in enumerate(chosen.itertuples(index=False)):
        params = {**defaults, **{c: getattr(row, c) for c in ("Ms", "A_ex", "K_u", "D", "N_pin", "sigma_theta_deg", "sigma_K")
                                 if hasattr(row, c)}}
        params["N_pin"] = int(params["N_pin"])
        family = resimulate(cfg, params, n_profiles=1)
        families[int(row.sample_id)] = family
        error = observation_error(curves_by_id[int(row.sample_id)], family)
        rows.append({**row._asdict(), "observation_rms": error["rms"]})
        if progress is not None:
            progress(k + 1, len(chosen))
    return pd.DataFrame(rows), families


def figure4(out_path, fields, truths: dict, resims: dict, sample_ids) -> None:
    """Ten test samples: input FORCs (red) and the re-simulated ones (dark), every 4th curve."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sample_ids = list(sample_ids)
    cols = 5
    rows = max(1, int(np.ceil(len(sample_ids) / cols)))
    fig, axes = plt.subplots(rows, cols, figsize=(3.0 * cols, 2.6 * rows), squeeze=False, sharex=True, sharey=True)
    for ax in axes.flat[len(sample_ids):]:
        ax.axis("off")
    for ax, sid in zip(axes.flat, sample_ids):
        truth, resim = truths[sid], resims[sid]
        for i in range(0, fields.size, 4):
            ax.plot(fields[i:], truth[i, i:], color="tab:red", lw=0.7)
            ax.plot(fields[i:], resim[i, i:], color="0.15", lw=0.7, ls="--")
        rms = observation_error(truth, resim)["rms"]
        ax.set_title(f"ID {sid}: RMS {rms:.3f}", fontsize=8)
    for ax in axes[-1]:
        ax.set_xlabel(r"$\mu_0H$ (T)")
    for ax in axes[:, 0]:
        ax.set_ylabel(r"$m_z$")
    fig.suptitle("closed loop: input FORCs (red) vs re-simulated from the predicted Hamiltonian (dashed)", fontsize=9)
    fig.tight_layout()
    fig.savefig(out_path, dpi=130)
    plt.close(fig)


def correlation_figure(out_path, table: pd.DataFrame) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(4.5, 3.6))
    ax.scatter(table["bob_error_mean"], table["observation_rms"], s=16)
    ax.set(xlabel="Bob's predicted error (mean over parameters)", ylabel="observation-space RMS of m",
           title="closed loop vs Bob")
    fig.tight_layout()
    fig.savefig(out_path, dpi=130)
    plt.close(fig)
