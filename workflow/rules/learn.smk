rule train_parameter:
    """Alice and Bob for one parameter: splits, K-fold cross-fitting, conformal intervals, MC dropout."""
    input:
        config=rules.resolve_learning.output,
        dataset=rules.merge.output.h5,
    output:
        model=f"{RESULTS}/models/{{parameter}}.pt",
        predictions=f"{RESULTS}/learn/{{parameter}}_predictions.parquet",
        metrics=f"{RESULTS}/learn/{{parameter}}_metrics.json",
    log:
        f"{RESULTS}/logs/learn/{{parameter}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/train_parameter/{{parameter}}.tsv"
    conda:
        CONDA_ENV
    threads: config["learning"]["threads"]
    resources:
        mem_mb=4000 if config["learning"]["model"] == "small" else 16000,
        runtime=240,
    params:
        cli=FORCDECODE_1T,
    shell:
        "{params.cli} learn train --config {input.config} --dataset {input.dataset} --parameter {wildcards.parameter} "
        "--model {output.model} --predictions {output.predictions} --metrics {output.metrics} --threads {threads} 2> {log}"


rule evaluate:
    """metrics.json (test split) and the learning figures: Figure 3, Figure 5b-c, learning and retention curves."""
    input:
        metrics=expand(f"{RESULTS}/learn/{{parameter}}_metrics.json", parameter=LEARN_PARAMETERS),
        predictions=expand(
            f"{RESULTS}/learn/{{parameter}}_predictions.parquet",
            parameter=LEARN_PARAMETERS,
        ),
        models=expand(f"{RESULTS}/models/{{parameter}}.pt", parameter=LEARN_PARAMETERS),
        dataset=rules.merge.output.h5,
        config=rules.resolve_learning.output,
        # the frozen networks' sealed-set figures (sealed.smk), reported beside the test split's
        sealed=[f"{RESULTS}/sealed/alice.json"] if SEALED_ON else [],
    output:
        metrics=f"{RESULTS}/metrics.json",
        table=f"{RESULTS}/metrics.md",
        figure3=report(
            f"{RESULTS}/figures/figure3.png",
            caption="../report/figure3.rst",
            category="2. Learning",
            labels={"name": "Figure 3: predicted against true", "kind": "figure"},
        ),
        figure5bc=report(
            f"{RESULTS}/figures/figure5bc.png",
            caption="../report/figure5bc.rst",
            category="2. Learning",
            labels={"name": "Figure 5b-c: Bob's predicted error", "kind": "figure"},
        ),
        learning_curve=report(
            f"{RESULTS}/figures/learning_curve.png",
            caption="../report/learning_curve.rst",
            category="2. Learning",
            labels={"name": "Learning curve", "kind": "figure"},
        ),
        learning_curve_json=f"{RESULTS}/learning_curve.json",
        retention=report(
            f"{RESULTS}/figures/retention.png",
            caption="../report/retention.rst",
            category="2. Learning",
            labels={"name": "Error-retention curves", "kind": "figure"},
        ),
        uncertainty=report(
            f"{RESULTS}/figures/uncertainty_baselines.png",
            caption="../report/uncertainty_baselines.rst",
            category="2. Learning",
            labels={"name": "Uncertainty against its baselines", "kind": "figure"},
        ),
    log:
        f"{RESULTS}/logs/evaluate.log",
    benchmark:
        f"{RESULTS}/benchmarks/evaluate/evaluate.tsv"
    conda:
        CONDA_ENV
    params:
        cli=FORCDECODE,
        figures=lambda wildcards, output: os.path.dirname(output.figure3),
        models=lambda wildcards, input: os.path.dirname(input.models[0]),
        sealed=lambda wildcards, input: f"--sealed {input.sealed}" if input.sealed else "",
    shell:
        "{params.cli} learn evaluate --metrics {input.metrics} --predictions {input.predictions} "
        "--out {output.metrics} --learning-curve {output.learning_curve_json} --figures {params.figures} "
        "--dataset {input.dataset} --config {input.config} --models {params.models} {params.sealed} > {log} 2>&1"


rule closed_loop:
    """Closed loop on the simulated test set: re-simulate the predicted Hamiltonians (Figure 4), the
    observation-space error and its correlation with Bob's predicted error."""
    input:
        config=rules.resolve_config.output,
        learning=rules.resolve_learning.output,
        dataset=rules.merge.output.h5,
        predictions=expand(
            f"{RESULTS}/learn/{{parameter}}_predictions.parquet",
            parameter=LEARN_PARAMETERS,
        ),
    output:
        summary=f"{RESULTS}/closed_loop.json",
        table=f"{RESULTS}/closed_loop.parquet",
        figure4=report(
            f"{RESULTS}/figures/figure4.png",
            caption="../report/figure4.rst",
            category="3. Closed loop",
            labels={"name": "Figure 4: re-simulated families", "kind": "figure"},
        ),
        correlation=report(
            f"{RESULTS}/figures/closed_loop_vs_bob.png",
            caption="../report/closed_loop_vs_bob.rst",
            category="3. Closed loop",
            labels={"name": "Observation error against Bob", "kind": "figure"},
        ),
        floor_null=report(
            f"{RESULTS}/figures/closed_loop_floor_null.png",
            caption="../report/closed_loop_floor_null.rst",
            category="3. Closed loop",
            labels={"name": "Observation error: floor and null", "kind": "figure"},
        ),
    log:
        f"{RESULTS}/logs/closed_loop.log",
    benchmark:
        f"{RESULTS}/benchmarks/closed_loop/closed_loop.tsv"
    conda:
        CONDA_ENV
    threads: 2
    resources:
        runtime=240,
    params:
        cli=FORCDECODE_1T,
        figures=lambda wildcards, output: os.path.dirname(output.figure4),
    shell:
        "{params.cli} closed-loop --config {input.config} --learning {input.learning} --dataset {input.dataset} "
        "--predictions {input.predictions} --out {output.summary} --table {output.table} --figures {params.figures} "
        "--workers {threads} 2> {log}"


rule train_posterior:
    """Neural posterior of all learned parameters (CNN embedding + neural spline flow) on the train split,
    early stopping on validation, calibrated on test (SBC ranks, coverage, MAE). In `all` since
    2026-11-28; its test figures go to posterior/metrics_test.json, and posterior_report (sealed.smk)
    writes posterior/metrics.json with the sealed set's beside them (without a sealed set: metrics.json)."""
    input:
        config=rules.resolve_learning.output,
        dataset=rules.merge.output.h5,
    output:
        model=f"{RESULTS}/posterior/model.pt",
        metrics=POSTERIOR_TEST_METRICS,
        figure=report(
            f"{RESULTS}/posterior/figures/posterior_calibration.png",
            caption="../report/posterior_calibration.rst",
            category="2. Learning",
            labels={"name": "Posterior calibration", "kind": "figure"},
        ),
    log:
        f"{RESULTS}/logs/posterior.log",
    benchmark:
        f"{RESULTS}/benchmarks/train_posterior/train_posterior.tsv"
    conda:
        CONDA_ENV
    threads: config["posterior"]["threads"]
    resources:
        mem_mb=4000,
        runtime=240,
    params:
        cli=FORCDECODE_1T,
        settings=json.dumps(config["posterior"], sort_keys=True),
        figures=lambda wildcards, output: os.path.dirname(output.figure),
    shell:
        "{params.cli} learn posterior --config {input.config} --dataset {input.dataset} --settings {params.settings:q} "
        "--model {output.model} --metrics {output.metrics} --figures {params.figures} --threads {threads} 2> {log}"


rule posterior_check:
    """The posterior scored on a fresh draw of the same configuration (another id range, built first
    with `--config first_sample_id=F n_samples=N results_dir=results/fresh/NAME`): SBC, coverage, TARP,
    PIT, OOD false alarms. Not in `all`: `snakemake results/posterior/fresh/NAME.json`."""
    input:
        model=rules.train_posterior.output.model,
        dataset=rules.merge.output.h5,
        fresh=f"{RESULTS}/fresh/{{draw}}/dataset.h5",
    output:
        metrics=f"{RESULTS}/posterior/fresh/{{draw}}.json",
        figure=report(
            f"{RESULTS}/posterior/fresh/{{draw}}.png",
            caption="../report/posterior_fresh.rst",
            category="2. Learning",
            labels={"name": "Posterior on a fresh draw ({draw})", "kind": "figure"},
        ),
    log:
        f"{RESULTS}/logs/posterior_check/{{draw}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/posterior_check/{{draw}}.tsv"
    conda:
        CONDA_ENV
    threads: config["posterior"]["threads"]
    params:
        cli=FORCDECODE_1T,
    shell:
        "{params.cli} learn posterior-check --posterior {input.model} --dataset {input.fresh} "
        "--training-dataset {input.dataset} --out {output.metrics} --figure {output.figure} --threads {threads} 2> {log}"


rule recalibrate_posterior:
    """The posterior's quantile recalibration refitted on a fresh draw (`results/fresh/CAL`, built as for
    `posterior_check`), which holds more families than the validation + calibration splits; the model
    with the new map, and the map's report with the test split scored. Not in `all`:
    `snakemake results/posterior/recalibrated/CAL/model.pt`."""
    input:
        model=rules.train_posterior.output.model,
        config=rules.resolve_learning.output,
        dataset=rules.merge.output.h5,
        fresh=f"{RESULTS}/fresh/{{cal}}/dataset.h5",
    output:
        model=f"{RESULTS}/posterior/recalibrated/{{cal}}/model.pt",
        report=f"{RESULTS}/posterior/recalibrated/{{cal}}/recalibration.json",
    log:
        f"{RESULTS}/logs/recalibrate_posterior/{{cal}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/recalibrate_posterior/{{cal}}.tsv"
    conda:
        CONDA_ENV
    threads: config["posterior"]["threads"]
    params:
        cli=FORCDECODE_1T,
    shell:
        "{params.cli} learn posterior-recalibrate --posterior {input.model} --dataset {input.fresh} "
        "--training-dataset {input.dataset} --config {input.config} --out {output.model} --report {output.report} "
        "--threads {threads} > {log} 2>&1"


rule posterior_check_recalibrated:
    """The posterior recalibrated on fresh draw CAL scored on another fresh draw DRAW. Not in `all`:
    `snakemake results/posterior/recalibrated/CAL/fresh/DRAW.json`."""
    input:
        model=rules.recalibrate_posterior.output.model,
        fresh=f"{RESULTS}/fresh/{{draw}}/dataset.h5",
    output:
        metrics=f"{RESULTS}/posterior/recalibrated/{{cal}}/fresh/{{draw}}.json",
        figure=report(
            f"{RESULTS}/posterior/recalibrated/{{cal}}/fresh/{{draw}}.png",
            caption="../report/posterior_fresh.rst",
            category="2. Learning",
            labels={"name": "Posterior recalibrated on {cal}, on a fresh draw ({draw})", "kind": "figure"},
        ),
    log:
        f"{RESULTS}/logs/posterior_check_recalibrated/{{cal}}/{{draw}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/posterior_check_recalibrated/{{cal}}/{{draw}}.tsv"
    conda:
        CONDA_ENV
    threads: config["posterior"]["threads"]
    params:
        cli=FORCDECODE_1T,
    shell:
        "{params.cli} learn posterior-check --posterior {input.model} --dataset {input.fresh} "
        "--out {output.metrics} --figure {output.figure} --threads {threads} 2> {log}"


rule tune_posterior:
    """The posterior architecture chosen on validation only: every candidate of
    forcdecode.learn.posterior_tune fitted on train and scored by its validation likelihood. Not in
    `all`: `snakemake results/posterior/tuning.json`; put the chosen settings in the config's
    `posterior` section."""
    input:
        config=rules.resolve_learning.output,
        dataset=rules.merge.output.h5,
    output:
        f"{RESULTS}/posterior/tuning.json",
    log:
        f"{RESULTS}/logs/posterior_tune.log",
    benchmark:
        f"{RESULTS}/benchmarks/tune_posterior/tune_posterior.tsv"
    conda:
        CONDA_ENV
    threads: config["posterior"]["threads"]
    resources:
        mem_mb=4000,
        runtime=480,
    params:
        cli=FORCDECODE_1T,
    shell:
        "{params.cli} learn posterior-tune --config {input.config} --dataset {input.dataset} --out {output} "
        "--threads {threads} 2> {log}"


rule posterior_closed_loop:
    """Posterior draws of the test families re-simulated against the floor (truth on the same new
    disorder). Not in `all`: `snakemake results/posterior/closed_loop.json` (needs train_posterior)."""
    input:
        config=rules.resolve_config.output,
        learning=rules.resolve_learning.output,
        dataset=rules.merge.output.h5,
        model=rules.train_posterior.output.model,
    output:
        summary=f"{RESULTS}/posterior/closed_loop.json",
        table=f"{RESULTS}/posterior/closed_loop.parquet",
        figure=report(
            f"{RESULTS}/posterior/figures/posterior_closed_loop.png",
            caption="../report/posterior_closed_loop.rst",
            category="3. Closed loop",
            labels={"name": "Posterior-predictive closed loop", "kind": "figure"},
        ),
    log:
        f"{RESULTS}/logs/posterior_closed_loop.log",
    benchmark:
        f"{RESULTS}/benchmarks/posterior_closed_loop/posterior_closed_loop.tsv"
    conda:
        CONDA_ENV
    threads: 2
    resources:
        runtime=240,
    params:
        cli=FORCDECODE_1T,
    shell:
        "{params.cli} posterior-loop --config {input.config} --learning {input.learning} --dataset {input.dataset} "
        "--posterior {input.model} --out {output.summary} --table {output.table} --figure {output.figure} "
        "--workers {threads} 2> {log}"
