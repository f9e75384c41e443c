"""Ablation: the paper's exact network against the laptop head, same data, split and optimizer.

    python -m forcdecode.bench.learn_ablation results/dataset.h5 [--parameters K_u D] [--epochs 40]

Prints, per parameter and network, the test MAE, Pearson r, best epoch, training throughput
(samples/s) and wall time: what the smaller default head costs (or saves) on this machine.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import torch

from ..learn.data import load_dataset
from ..learn.pipeline import DEFAULT_SETTINGS, make_splits
from ..learn.train import fit_alice


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset")
    parser.add_argument("--parameters", nargs="+", default=["K_u", "D"])
    parser.add_argument("--epochs", type=int, default=40)
    parser.add_argument("--patience", type=int, default=10)
    parser.add_argument("--seed", type=int, default=20261122)
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    data = load_dataset(args.dataset)
    splits = make_splits(len(data), args.seed, DEFAULT_SETTINGS)
    rows = []
    for name in args.parameters:
        u = data.target(name)
        for model in ("small", "paper"):
            started = time.perf_counter()
            alice = fit_alice(data.images, data.ms_norm, u, splits["train"], splits["validation"], model=model,
                              epochs=args.epochs, patience=args.patience, batch_size=8, lr=1.0, seed=1)
            wall = time.perf_counter() - started
            test = splits["test"]
            prediction = alice.predict(data.images[test], data.ms_norm[test])
            row = {"parameter": name, "network": model, "test_mae": float(np.abs(prediction - u[test]).mean()),
                   "pearson_r": float(np.corrcoef(prediction, u[test])[0, 1]), "best_epoch": alice.best_epoch,
                   "samples_per_s": alice.history["samples_seen"] / alice.history["train_seconds"], "wall_s": wall,
                   "weights": sum(p.numel() for p in alice.net.parameters())}
            rows.append(row)
            print(json.dumps(row), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
