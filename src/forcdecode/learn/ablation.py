"""Head ablation: the seed paper's exact network against the laptop head, same data and protocol.

Both networks of a parameter are trained in one run on the same split (the workflow's
train / validation / test, from the config seed), with the same optimizer (Adadelta ρ 0.9), learning
rate, batch size, epoch budget, early-stopping patience and weight seed; only the dense block
differs (paper: 57,600 + 625 → 4,096 → 11; small: 4×4 pool, 3,600 + 625 → width → 11). Reported on
the test split: MAE on [0, 1], Pearson r, skill against the train median, best epoch, training
throughput (samples/s) and wall time, and per parameter the paper/small ratios of wall time and
throughput (ratios from one run: the machine's load cancels).

    forcdecode bench learn --dataset results/dataset.h5 [--parameters K_u D] [--out results/bench/heads.json]
"""

from __future__ import annotations

import time

import numpy as np

from .pipeline import scores
from .train import fit_alice

HEADS = ("small", "paper")


def compare_heads(images, ms_norm, targets: dict, splits: dict, *, heads=HEADS, epochs: int = 40,
                  patience: int = 10, batch_size: int = 8, lr: float = 1.0, width: int = 256, seed: int = 1,
                  log=None) -> list[dict]:
    """Train every head on every target (name → normalized u ∈ [0, 1]); one row per (target, head)."""
    train, val, test = (np.asarray(splits[k]) for k in ("train", "validation", "test"))
    rows = []
    for name, u in targets.items():
        u = np.asarray(u, float)
        for head in heads:
            if log is not None:
                log(f"{name}: training the {head} network ({len(train)} train / {len(val)} validation samples)")
            started = time.perf_counter()
            alice = fit_alice(images, ms_norm, u, train, val, model=head, width=width, epochs=epochs,
                              patience=patience, batch_size=batch_size, lr=lr, seed=seed,
                              log=None if log is None else (lambda text, n=name, h=head: log(f"{n} [{h}] {text}")))
            wall = time.perf_counter() - started
            prediction = alice.predict(images[test], ms_norm[test])
            row = {"parameter": name, "network": head, "weights": int(sum(p.numel() for p in alice.net.parameters())),
                   "n_train": int(len(train)), "n_test": int(len(test)),
                   **scores(u[test], prediction, float(np.median(u[train]))),
                   "best_epoch": int(alice.best_epoch), "epochs_run": len(alice.history["val_loss"]),
                   "samples_per_s": alice.history["samples_seen"] / alice.history["train_seconds"],
                   "wall_s": wall}
            rows.append(row)
            if log is not None:
                log(f"{name} [{head}]: test MAE {row['mae']:.3f} (baseline {row['baseline_mae']:.3f}), "
                    f"r {row['pearson_r']:.2f}, {row['samples_per_s']:.1f} samples/s, {wall:.0f} s")
    return rows


def head_ratios(rows: list[dict], numerator: str = "paper", denominator: str = "small") -> dict:
    """Per parameter: wall-time and throughput ratios and the MAE difference between two heads."""
    by_key = {(row["parameter"], row["network"]): row for row in rows}
    ratios = {}
    for name in dict.fromkeys(row["parameter"] for row in rows):
        a, b = by_key.get((name, numerator)), by_key.get((name, denominator))
        if a is None or b is None:
            continue
        ratios[name] = {"wall_ratio": a["wall_s"] / b["wall_s"],
                        "throughput_ratio": a["samples_per_s"] / b["samples_per_s"],
                        "weights_ratio": a["weights"] / b["weights"],
                        "mae_difference": a["mae"] - b["mae"]}
    return ratios
