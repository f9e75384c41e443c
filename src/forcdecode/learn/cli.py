"""``forcdecode learn train|evaluate|posterior`` (workflow stages) and ``forcdecode predict`` (the user command).

    learn train     --config C --dataset dataset.h5 --parameter P --model M.pt --predictions X.parquet --metrics J.json
    learn evaluate  --metrics J.json... --predictions X.parquet... --out metrics.json --figures DIR
                    [--dataset dataset.h5 --config learning.json --models results/models]
    learn posterior --config C --dataset dataset.h5 --model results/posterior/model.pt
                    --metrics results/posterior/metrics.json --figures DIR [--settings JSON]
    learn posterior-tune --config C --dataset dataset.h5 --out results/posterior/tuning.json
    learn posterior-check --posterior results/posterior/model.pt --dataset FRESH/dataset.h5 --out J.json
    learn posterior-recalibrate --posterior results/posterior/model.pt --dataset FRESH/dataset.h5 --out M.pt
    learn posterior-splits  (coverage per held-out split of the training dataset; defaults: results/)
    learn sealed    --models results/models --dataset dataset.h5 --sealed sealed/dataset.h5 --config learning.json
                    --out sealed/alice.json   (the frozen networks on the sealed set, once, at the end)
    learn attach-sealed --metrics J.json --sealed S.json --out metrics.json
                    --report J.json [--training-dataset dataset.h5 --config learning.json]
    predict INPUT --Ms-kA-m 800 --models results/models [--json]
    predict INPUT --Ms-kA-m 800 --estimator posterior --posterior results/posterior/model.pt [--json]
        INPUT: a FORC file (any format `forcdecode read` knows), a 64×64 image (.npy, uint8 or m in [−1, 1]),
        or dataset.h5 with --sample-id.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

from ..config import defaults
from ..core.errors import ConfigError
from ..core.io import read_config, read_json, write_json
from ..core.parameters import TARGETS
from .answer import alice_answer
from .compare import compare_estimators, comparison_markdown
from .data import load_dataset
from .estimator_choice import add_estimator_arguments, choose_estimator, default_posterior_path
from .posterior_check import (apply_recalibration, check_lines, fresh_calibration, fresh_recalibration,
                              recalibration_lines, split_coverage, split_coverage_lines, write_check)
from .prior_class import check_prior_class
from .report import TrainingDataset, evaluate, markdown
from .sealed import alice_sealed_metrics, attach_sealed, sealed_lines
from .shipped import check_thickness, models_thickness_nm, resolve_models
from .splits import assign_splits


def _log(text: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {text}", file=sys.stderr, flush=True)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="step", required=True)
    p = sub.add_parser("train", help="fit Alice and Bob for one parameter")
    p.add_argument("--config", required=True, help="resolved config.json")
    p.add_argument("--dataset", required=True)
    p.add_argument("--parameter", required=True)
    p.add_argument("--model", required=True, help="output model file (.pt)")
    p.add_argument("--predictions", required=True, help="output per-sample predictions (.parquet)")
    p.add_argument("--metrics", required=True, help="output metrics (.json)")
    p.add_argument("--threads", type=int, default=1)
    p = sub.add_parser("evaluate", help="metrics.json and the learning figures")
    p.add_argument("--metrics", nargs="+", required=True)
    p.add_argument("--predictions", nargs="+", required=True)
    p.add_argument("--out", required=True, help="metrics.json")
    p.add_argument("--learning-curve", help="learning_curve.json (default: beside --out)")
    p.add_argument("--figures", required=True)
    p.add_argument("--dataset", help="dataset.h5 the networks were trained on: adds the derived combinations "
                                     "(sigma_w, delta_w, D/D_c, Q) of Alice's predictions to metrics.json")
    p.add_argument("--config", help="resolved learning.json (seed and bootstrap of the combinations' intervals)")
    p.add_argument("--models", help="directory of the <parameter>.pt files (with --dataset: the combinations' "
                                    "images-shuffled baseline)")
    p.add_argument("--sealed", help="the sealed set's figures (learn sealed): metrics.json gains them as `sealed`")
    p = sub.add_parser("sealed", help="the frozen networks scored once on the sealed set (a separate id range)")
    p.add_argument("--models", required=True, help="directory of the <parameter>.pt files")
    p.add_argument("--dataset", required=True, help="dataset.h5 the networks were trained on (baselines, splits)")
    p.add_argument("--sealed", required=True, help="dataset.h5 of the sealed families")
    p.add_argument("--config", required=True, help="resolved learning.json (seed, split, bootstrap)")
    p.add_argument("--out", required=True, help="output JSON")
    p = sub.add_parser("attach-sealed", help="a metrics JSON with the sealed set's figures added as `sealed`")
    p.add_argument("--metrics", required=True, help="metrics JSON of the test split")
    p.add_argument("--sealed", required=True, help="the sealed set's figures (JSON)")
    p.add_argument("--out", required=True, help="output metrics JSON")
    p = sub.add_parser("posterior", help="neural posterior estimate of all parameters, calibrated on the test split")
    p.add_argument("--config", required=True, help="resolved learning.json (seed, learning.split; a posterior section if any)")
    p.add_argument("--dataset", required=True)
    p.add_argument("--model", required=True, help="output posterior model (.pt)")
    p.add_argument("--metrics", required=True, help="output calibration metrics (.json)")
    p.add_argument("--figures", required=True, help="directory of the calibration figure")
    p.add_argument("--settings", help="posterior settings as JSON (override the config's posterior section)")
    p.add_argument("--threads", type=int, default=1)
    p = sub.add_parser("compare", help="Alice + Bob + conformal against the posterior on the same test families")
    p.add_argument("--metrics", default="results/metrics.json", help="Alice's aggregated metrics.json")
    p.add_argument("--posterior", default="results/posterior/metrics.json", help="the posterior's metrics.json")
    p.add_argument("--out", help="also write the table as JSON")
    p = sub.add_parser("posterior-check", help="calibration of a saved posterior on fresh families (another id range "
                                               "of the same configuration, never seen in training)")
    p.add_argument("--posterior", required=True, help="the posterior model (.pt)")
    p.add_argument("--dataset", required=True, help="dataset.h5 of the fresh families")
    p.add_argument("--out", required=True, help="output calibration metrics (.json)")
    p.add_argument("--figure", help="rank histograms and coverage curves (.png)")
    p.add_argument("--training-dataset", help="the dataset the posterior was trained on (only for models saved "
                                              "without the ids they were fitted on)")
    p.add_argument("--seed", type=int, help="seed of the posterior draws (default: the model's)")
    p.add_argument("--draws", type=int, default=1000)
    p.add_argument("--config", help="resolved learning.json: with --training-dataset, the derived combinations "
                                    "(sigma_w, ...) are scored too, their baselines fitted on its train split")
    p.add_argument("--threads", type=int, default=1)
    p = sub.add_parser("posterior-splits", help="coverage of a saved posterior on each held-out split of its own "
                                                "training dataset (validation, calibration, test)")
    p.add_argument("--posterior", default="results/posterior/model.pt", help="the posterior model (.pt)")
    p.add_argument("--dataset", default="results/dataset.h5", help="the dataset it was trained on")
    p.add_argument("--config", default="results/learning.json", help="resolved learning.json of the training run "
                                                                    "(seed, split)")
    p.add_argument("--out", help="also write the table as JSON")
    p.add_argument("--draws", type=int, default=1000)
    p.add_argument("--threads", type=int, default=1)
    p = sub.add_parser("posterior-recalibrate", help="refit the posterior's quantile recalibration on a fresh draw "
                                                     "(another id range of the same configuration) and save the model")
    p.add_argument("--posterior", required=True, help="the posterior model (.pt)")
    p.add_argument("--dataset", required=True, help="dataset.h5 of the fresh families the map is fitted on")
    p.add_argument("--out", required=True, help="output posterior model (.pt), the input's flow with the new map")
    p.add_argument("--report", required=True, help="output JSON: the map, its likelihood-ratio p-values, and with "
                                                   "--config the recalibrated model scored on the test split")
    p.add_argument("--training-dataset", help="the dataset the posterior was trained on (its test split is scored "
                                              "with --config; needed for models saved without their fitted ids)")
    p.add_argument("--config", help="resolved learning.json of the training run (seed, split): score the test split")
    p.add_argument("--gate-alpha", type=float, help="apply a parameter's map only where its likelihood-ratio p "
                                                    "lies below this (default: the model's posterior setting)")
    p.add_argument("--seed", type=int, help="seed of the posterior draws (default: the model's)")
    p.add_argument("--draws", type=int, default=1000)
    p.add_argument("--threads", type=int, default=1)
    p = sub.add_parser("posterior-tune", help="choose the posterior architecture on the validation split only")
    p.add_argument("--config", required=True, help="resolved learning.json (seed, split, posterior section)")
    p.add_argument("--dataset", required=True)
    p.add_argument("--out", required=True, help="output table (.json): every candidate's validation scores, the choice")
    p.add_argument("--candidates", help="JSON list of partial posterior settings to compare (default: the built-in list)")
    p.add_argument("--weight-seeds", type=int, default=1, help="weight seeds per candidate (scores averaged)")
    p.add_argument("--threads", type=int, default=1)


def _step_train(args) -> int:
    """`forcdecode learn train`."""
    import torch  # heavy: only the steps that train or sample load it

    from .pipeline import train_parameter

    torch.set_num_threads(max(1, args.threads))
    cfg = read_config(args.config)
    if args.parameter not in TARGETS:
        raise ConfigError(f"unknown parameter {args.parameter!r} (one of {', '.join(TARGETS)})")
    data = load_dataset(args.dataset)
    metrics = train_parameter(data, args.parameter, cfg.get("learning", {}), cfg["seed"], args.model,
                              args.predictions, log=_log)
    write_json(args.metrics, json.loads(json.dumps(metrics, default=float)))
    return 0


def _step_posterior(args) -> int:
    """`forcdecode learn posterior`."""
    import torch  # heavy: only the steps that train or sample load it

    from pathlib import Path

    from .posterior import train_posterior

    torch.set_num_threads(max(1, args.threads))
    cfg = read_config(args.config)
    settings = dict(cfg.get("posterior") or {})
    if args.settings:
        try:
            settings.update(json.loads(args.settings))
        except (json.JSONDecodeError, TypeError, ValueError) as error:
            raise ConfigError(f"--settings is not a JSON mapping: {error}") from None
    data = load_dataset(args.dataset)
    train_posterior(data, settings, cfg.get("learning", {}), cfg["seed"], args.model, args.metrics,
                    Path(args.figures) / "posterior_calibration.png", log=_log)
    return 0


def _step_posterior_check(args) -> int:
    """`forcdecode learn posterior-check`."""
    import torch  # heavy: only the steps that train or sample load it

    from .posterior import PosteriorEstimator

    torch.set_num_threads(max(1, args.threads))
    est = PosteriorEstimator.load(args.posterior)
    training = load_dataset(args.training_dataset) if args.training_dataset else None
    seed = args.seed if args.seed is not None else int(est.metadata.get("seed", 0))
    levels = (est.metadata.get("settings") or {}).get("levels")  # None: the posterior section's default
    learning, split_seed = None, None
    if args.config:
        cfg = read_config(args.config)
        learning, split_seed = {**defaults("learning"), **(cfg.get("learning") or {})}, int(cfg["seed"])
    metrics = fresh_calibration(est, load_dataset(args.dataset), seed=seed, draws=args.draws, levels=levels,
                                training_data=training, learning=learning, split_seed=split_seed)
    write_check(metrics, args.out, args.figure)
    for line in check_lines(metrics):
        print(line)
    return 0


def _step_posterior_splits(args) -> int:
    """`forcdecode learn posterior-splits`."""
    import torch  # heavy: only the steps that train or sample load it

    from .posterior import PosteriorEstimator

    torch.set_num_threads(max(1, args.threads))
    est = PosteriorEstimator.load(args.posterior)
    cfg = read_config(args.config)
    learning = {**defaults("learning"), **(cfg.get("learning") or {})}
    table = split_coverage(est, load_dataset(args.dataset), seed=int(est.metadata.get("seed", cfg["seed"])),
                           split_seed=int(cfg["seed"]), learning=learning, draws=args.draws,
                           levels=(est.metadata.get("settings") or {}).get("levels"))
    if args.out:
        write_json(args.out, table)
    for line in split_coverage_lines(table):
        print(line)
    return 0


def _step_posterior_recalibrate(args) -> int:
    """`forcdecode learn posterior-recalibrate`."""
    import torch  # heavy: only the steps that train or sample load it

    from .posterior import PosteriorEstimator

    torch.set_num_threads(max(1, args.threads))
    est = PosteriorEstimator.load(args.posterior)
    training = load_dataset(args.training_dataset) if args.training_dataset else None
    seed = args.seed if args.seed is not None else int(est.metadata.get("seed", 0))
    fresh = load_dataset(args.dataset)
    record = fresh_recalibration(est, fresh, seed=seed, draws=args.draws, training_data=training,
                                 gate_alpha=args.gate_alpha)
    est.metadata = apply_recalibration(est, record, fresh.sample_id, training)
    report = {"recalibration": record, "test_split": None}
    if args.config:
        if training is None:
            raise ConfigError("--config scores the training run's test split: pass --training-dataset too")
        cfg = read_config(args.config)
        learning = {**defaults("learning"), **(cfg.get("learning") or {})}
        test = assign_splits(training.sample_id, cfg["seed"], learning["split"], learning["protocol"])["test"]
        levels = (est.metadata.get("settings") or {}).get("levels")
        report["test_split"] = fresh_calibration(est, training.take(test), seed=seed, draws=args.draws,
                                                 levels=levels)
        report["test_split"]["reported_on"] = "the training run's test split, recalibrated on the fresh draw"
    est.save(args.out, **est.metadata)
    write_json(args.report, json.loads(json.dumps(report, default=float)))
    for line in recalibration_lines(record):
        print(line)
    if report["test_split"] is not None:
        print("on the training run's test split:")
        for line in check_lines(report["test_split"])[1:]:
            print(line)
    return 0


def _step_compare(args) -> int:
    """`forcdecode learn compare`."""
    for line in comparison_markdown(compare_estimators(args.metrics, args.posterior, out=args.out)):
        print(line)
    return 0


def _step_posterior_tune(args) -> int:
    """`forcdecode learn posterior-tune`."""
    import torch  # heavy: only the steps that train or sample load it

    from .posterior_tune import tune_posterior, tuning_lines

    torch.set_num_threads(max(1, args.threads))
    cfg = read_config(args.config)
    from json import JSONDecodeError, loads

    from .posterior_tune import CANDIDATES, TuningPlan

    try:
        candidates = CANDIDATES if args.candidates is None else tuple(loads(args.candidates))
    except JSONDecodeError as error:
        raise ConfigError(f"--candidates is not a JSON list of settings: {error}") from None
    if not candidates or not all(isinstance(c, dict) for c in candidates):
        raise ConfigError(f"--candidates must be a non-empty JSON list of settings mappings, got {args.candidates}")
    plan = TuningPlan(candidates=candidates, weight_seeds=tuple(range(max(1, args.weight_seeds))))
    result = tune_posterior(load_dataset(args.dataset), dict(cfg.get("posterior") or {}), cfg.get("learning", {}),
                            cfg["seed"], plan, out=args.out, log=_log)
    for line in tuning_lines(result):
        print(line)
    return 0


def _step_evaluate(args) -> int:
    """`forcdecode learn evaluate`."""
    cfg = read_config(args.config) if args.config else {}
    n_boot = int({**defaults("learning"), **(cfg.get("learning") or {})}["bootstrap"])
    dataset = (TrainingDataset(args.dataset, seed=int(cfg.get("seed", 0)), n_boot=n_boot, models=args.models)
               if args.dataset is not None else None)
    metrics = evaluate(args.metrics, args.predictions, args.out, args.figures, args.learning_curve, dataset=dataset,
                       sealed=read_json(args.sealed, what="sealed figures") if args.sealed else None)
    print(markdown(metrics))
    return 0


def _step_sealed(args) -> int:
    """`forcdecode learn sealed`."""
    # loads torch: imported only when this runs
    from .predictor import load_models

    cfg = read_config(args.config)
    settings = {**defaults("learning"), **(cfg.get("learning") or {})}
    metrics = alice_sealed_metrics(load_models(args.models), load_dataset(args.dataset), load_dataset(args.sealed),
                                   seed=int(cfg["seed"]), settings=settings, n_boot=int(settings["bootstrap"]))
    write_json(args.out, json.loads(json.dumps(metrics, default=float)))
    for line in sealed_lines(metrics):
        print(line)
    return 0


def _step_attach_sealed(args) -> int:
    """`forcdecode learn attach-sealed`."""
    write_json(args.out, attach_sealed(read_json(args.metrics, what="metrics"),
                                       read_json(args.sealed, what="sealed figures")))
    return 0

STEPS = {
    "train": _step_train,
    "posterior": _step_posterior,
    "posterior-check": _step_posterior_check,
    "posterior-splits": _step_posterior_splits,
    "posterior-recalibrate": _step_posterior_recalibrate,
    "compare": _step_compare,
    "posterior-tune": _step_posterior_tune,
    "evaluate": _step_evaluate,
    "sealed": _step_sealed,
    "attach-sealed": _step_attach_sealed,
}
"""`forcdecode learn STEP`: each step's runner (args → exit status)."""


def run(args) -> int:
    return STEPS[args.step](args)


# ---------------------------------------------------------------- predict
def add_predict_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("input", help="FORC file, 64×64 image (.npy) or dataset.h5 (with --sample-id)")
    parser.add_argument("--Ms-kA-m", dest="ms_kA_m", type=float, required=True, help="saturation magnetization M_s (kA/m)")
    parser.add_argument("--sample-id", type=int, help="sample of dataset.h5 to read")
    parser.add_argument("--B-max-T", type=float, default=1.0, help="field window of the training grid (FORC files)")
    parser.add_argument("--thickness-nm", type=float, default=None,
                        help="your film's thickness (nm): refused outside the range the models' thickness study "
                             "shows safe, unless --force (default: the models' own film, 4 nm for the shipped models)")
    parser.add_argument("--force", action="store_true", help="predict even when the FORC file is out of the training "
                        "domain or its loop contradicts the prior class the model was trained on")
    parser.add_argument("--json", action="store_true", help="machine-readable output")
    add_estimator_arguments(parser)
    parser.add_argument("--draws", type=int, default=4000,
                        help="posterior draws (--estimator posterior), or Monte-Carlo draws of Alice's intervals "
                             "behind the combinations' intervals (alice)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the posterior draws or of Alice's Monte-Carlo draws")


def run_predict(args) -> int:
    """Print the prediction (``predictor.prediction_lines``, or JSON): each parameter with its intervals and
    whether it is read from the image (``learn.answer``), and the derived combinations with theirs. First
    the prior-class check (``learn.prior_class``): a file whose loop contradicts the class the model was
    trained on raises PriorClassError (exit 2) unless ``--force``; the class is printed (JSON:
    ``prior_class``, ``prior_check``)."""
    # loads torch: imported only when this runs
    from .predictor import image_from_input, load_models, models_prior_class, predict_parameters, prediction_lines

    models_dir, models_line = resolve_models(args.models)
    args.models = str(models_dir)
    thickness_line = check_thickness(models_dir, args.thickness_nm, models_thickness_nm(models_dir), force=args.force)
    if not args.json:
        print(models_line)
        print(thickness_line)
    args.posterior = args.posterior or default_posterior_path(args.models)
    choice = None
    if args.estimator == "auto":
        choice = choose_estimator(args.models, args.posterior)
        args.estimator = choice["estimator"]
    if args.estimator == "posterior":
        # loads torch: imported only when this runs
        from .posterior import PosteriorEstimator, posterior_prediction

        estimator = PosteriorEstimator.load(args.posterior)
        trained_on = estimator.prior_class
        image, note = image_from_input(args.input, estimator.image_size, args.sample_id, args.B_max_T, args.force)
        check = check_prior_class(trained_on, image, force=args.force, source=args.input, B_max_T=args.B_max_T)
        result = posterior_prediction(estimator, image, args.ms_kA_m * 1e3, args.draws, args.seed)
    else:
        models = load_models(args.models)
        trained_on = models_prior_class(models)
        size = next(iter(models.values())).image_size
        image, note = image_from_input(args.input, size, args.sample_id, args.B_max_T, args.force)
        check = check_prior_class(trained_on, image, force=args.force, source=args.input, B_max_T=args.B_max_T)

        result = alice_answer(models, predict_parameters(models, image, args.ms_kA_m * 1e3), args.draws, args.seed)
    result["prior_class"], result["prior_check"] = trained_on, check
    result["models"] = models_line
    result["thickness"] = thickness_line
    if note:
        result["out_of_domain"] = note
    if choice is not None:
        result["estimator_choice"] = choice
        if not args.json:
            print(f"estimator: {choice['estimator']} (auto: {choice['basis']})")
    print(json.dumps(result, indent=2) if args.json else "\n".join(prediction_lines(result, args.input, args.ms_kA_m)))
    return 0
