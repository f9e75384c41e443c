"""Head ablation: the seed paper's exact network against the laptop head, same data and protocol.

Both networks of a parameter are trained in one run on the same split (the workflow's
train / validation / test, from the config seed), with the same optimizer (Adadelta ρ 0.9), learning
rate, batch size, epoch budget, early-stopping patience and weight seed; only the dense block
differs (paper: 57,600 + 625 → 4,096 → 11; small: 4×4 pool, 3,600 + 625 → width → 11). A choice
between heads is made on the validation figures (``validation_mae``, ``validation_mae_difference``);
the test split's MAE, Pearson r and skill against the train median are reported next to them, never
chosen on. Also: best epoch, training throughput (samples/s) and wall time, and per parameter the
paper/small ratios of wall time and throughput (ratios from one run: the machine's load cancels).

    forcdecode bench learn --dataset results/dataset.h5 [--parameters K_u D] [--out results/bench/heads.json]

Defaults (learning rate, batch size, width, epochs, patience) are the schema's learning defaults
(``forcdecode.config.defaults("learning")``); the weights of a parameter's networks derive from the
``ablation`` random stream of ``seed`` and the parameter name (the same for both heads).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch

from ..config import defaults
from ..core.errors import ConfigError, InputFileError
from ..core.io import read_config, write_json
from ..core.parameters import TARGETS
from ..core.streams import stream_seed
from .data import load_dataset
from .pipeline import make_splits, scores
from .train import AliceSettings, fit_alice

HEADS = ("small", "paper")


def compare_heads(images, ms_norm, targets: dict, splits: dict, *, heads=HEADS,
                  training: AliceSettings = AliceSettings(seed=1), log=None) -> list[dict]:
    """Train every head on every target (name → normalized u ∈ [0, 1]); one row per (target, head).
    ``training``: the settings shared by every network (its ``model`` is replaced by each head, its
    ``seed`` is the root of the ``ablation`` stream that seeds each parameter's networks); settings left
    None take the schema's learning defaults (resolved by ``fit_alice``)."""
    train, val, test = (np.asarray(splits[k]) for k in ("train", "validation", "test"))
    rows = []
    for name, u in targets.items():
        u = np.asarray(u, float)
        for head in heads:
            if log is not None:
                log(f"{name}: training the {head} network ({len(train)} train / {len(val)} validation samples)")
            started = time.perf_counter()
            network = replace(training, model=head, seed=stream_seed(training.seed, "ablation", name))
            alice = fit_alice(images, ms_norm, u, train, val, network,
                              log=None if log is None else (lambda text, n=name, h=head: log(f"{n} [{h}] {text}")))
            wall = time.perf_counter() - started
            prior = float(np.median(u[train]))
            validation = scores(u[val], alice.predict(images[val], ms_norm[val]), prior)
            prediction = alice.predict(images[test], ms_norm[test])
            row = {"parameter": name, "network": head, "weights": int(sum(p.numel() for p in alice.net.parameters())),
                   "n_train": int(len(train)), "n_validation": int(len(val)), "n_test": int(len(test)),
                   **{f"validation_{k}": v for k, v in validation.items()},
                   **scores(u[test], prediction, prior),
                   "best_epoch": int(alice.best_epoch), "epochs_run": len(alice.history["val_loss"]),
                   "samples_per_s": alice.history["samples_seen"] / alice.history["train_seconds"],
                   "wall_s": wall}
            rows.append(row)
            if log is not None:
                log(f"{name} [{head}]: validation MAE {row['validation_mae']:.3f} (the figure a choice is made on); "
                    f"test MAE {row['mae']:.3f} (baseline {row['baseline_mae']:.3f}), "
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
                        "validation_mae_difference": a["validation_mae"] - b["validation_mae"],
                        "mae_difference": a["mae"] - b["mae"]}
    return ratios


@dataclass(frozen=True)
class HeadAblation:
    """What the head ablation trains: ``parameters`` (names of ``core.parameters.TARGETS``), ``heads``
    (``learn.models`` heads), ``epochs`` (the most passes over the training split), ``patience`` (epochs
    without a lower validation loss before stopping), ``seed`` (root of the ``ablation`` random stream
    of the networks' weights) and ``threads`` (torch CPU threads)."""

    parameters: tuple = ("K_u", "D")
    heads: tuple = HEADS
    epochs: int = 40
    patience: int = 10
    seed: int = 1
    threads: int = 2


def run_head_ablation(dataset, ablation: HeadAblation = HeadAblation(), *, learning_config=None, out=None,
                      log=None) -> dict:
    """The ablation on the workflow's dataset: the split and the learning settings of its
    ``learning.json`` (default: beside the dataset), both heads per parameter, ``ablation.threads`` torch
    threads; writes ``out`` (JSON, atomically) if given and returns {"dataset", "n_families",
    "threads", "settings", "rows", "ratios"}."""
    parameters, heads, epochs, patience = ablation.parameters, ablation.heads, ablation.epochs, ablation.patience
    seed, threads = ablation.seed, ablation.threads
    unknown = sorted(set(parameters) - set(TARGETS))
    if unknown:
        raise ConfigError(f"unknown parameter(s) {unknown}; choose from {list(TARGETS)}")
    config_path = Path(learning_config or Path(dataset).with_name("learning.json"))
    if not config_path.exists():
        raise InputFileError(f"{config_path} not found: the ablation rebuilds the workflow's split from its "
                             "learning.json (pass --learning-config)")
    cfg = read_config(config_path)
    settings = {**defaults("learning"), **cfg.get("learning", {})}
    torch.set_num_threads(threads)
    data = load_dataset(dataset)
    splits = make_splits(data.sample_id, cfg["seed"], settings)
    if log is not None:
        log(f"{dataset}: {len(data)} families; split train {len(splits['train'])} / validation "
            f"{len(splits['validation'])} / test {len(splits['test'])}; Adadelta lr {settings['lr']}, batch "
            f"{settings['batch_size']}, {epochs} epochs (patience {patience}); {threads} torch threads")
    training = AliceSettings(width=settings["width"], epochs=epochs, batch_size=settings["batch_size"],
                             lr=settings["lr"], patience=patience, seed=seed)
    rows = compare_heads(data.images, data.ms_norm, {name: data.target(name) for name in parameters}, splits,
                         heads=heads, training=training, log=log)
    result = {"dataset": str(dataset), "n_families": len(data), "threads": threads,
              "settings": {"epochs": epochs, "patience": patience, "lr": settings["lr"],
                           "batch_size": settings["batch_size"], "width": settings["width"],
                           "optimizer": "Adadelta rho 0.9", "split_seed": cfg["seed"], "seed": seed},
              "rows": rows, "ratios": head_ratios(rows)}
    if out:
        write_json(out, result)
    return result


def summary_lines(result: dict) -> list[str]:
    """The ablation as a table (one line per parameter and head) and the paper/small ratios."""
    lines = ["parameter  network  weights     val. MAE  test MAE  r      skill  best/run epochs  samples/s  wall s"]
    for row in result["rows"]:
        lines.append(f"{row['parameter']:<10} {row['network']:<8} {row['weights'] / 1e6:7.2f} M  "
                     f"{row['validation_mae']:8.3f}  {row['mae']:8.3f}  "
                     f"{row['pearson_r']:5.2f}  {row['skill']:5.2f}  {row['best_epoch'] + 1:>4}/{row['epochs_run']:<4}        "
                     f"{row['samples_per_s']:9.1f}  {row['wall_s']:6.0f}")
    for name, ratio in result["ratios"].items():
        lines.append(f"{name}: paper/small wall time {ratio['wall_ratio']:.1f}x, throughput "
                     f"{ratio['throughput_ratio']:.3f}x, weights {ratio['weights_ratio']:.0f}x, validation MAE "
                     f"difference {ratio['validation_mae_difference']:+.3f} (the choice), test {ratio['mae_difference']:+.3f}")
    return lines
