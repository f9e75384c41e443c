# The sealed test set (config `sealed`; learn/sealed.py). Its chunks are screened and simulated by the
# rules of every chunk; here they are merged apart and scored once, at the end, by the frozen models.
# No rule that fits anything reads a file of this stage (tests/workflow/test_sealed_dag.py).

SEALED_SCREEN_CHUNKS = [f"{RESULTS}/screen/chunk_{c}.parquet" for c in SEALED_CHUNKS]
SEALED_PARAM_CHUNKS = [f"{RESULTS}/params/chunk_{c}.parquet" for c in SEALED_CHUNKS]
SEALED_FAMILY_LISTS = [f"{RESULTS}/families/chunk_{c}.json" for c in SEALED_CHUNKS]


if SEALED_ON:

    rule merge_sealed:
        """sealed/dataset.h5: the sealed id range's families (same configuration, never in dataset.h5)."""
        input:
            config=rules.resolve_config.output,
            params=SEALED_PARAM_CHUNKS,
            screens=SEALED_SCREEN_CHUNKS,
            families=SEALED_FAMILY_LISTS,
        output:
            h5=f"{RESULTS}/sealed/dataset.h5",
            parquet=f"{RESULTS}/sealed/samples.parquet",
        log:
            f"{RESULTS}/logs/merge_sealed.log",
        benchmark:
            f"{RESULTS}/benchmarks/merge/merge_sealed.tsv"
        conda:
            CONDA_ENV
        params:
            cli=FORCDECODE,
        shell:
            "{params.cli} dataset merge --config {input.config} --params {input.params} "
            "--screens {input.screens} --family-lists {input.families} --h5 {output.h5} --parquet {output.parquet} 2> {log}"

    rule score_sealed:
        """Alice and Bob, frozen, on the sealed set: MAE, skill over the trivial predictors (fitted on the
        training dataset's train split) with bootstrap intervals, coverage; the derived combinations."""
        input:
            config=rules.resolve_learning.output,
            dataset=rules.merge.output.h5,
            sealed=rules.merge_sealed.output.h5,
            models=expand(f"{RESULTS}/models/{{parameter}}.pt", parameter=LEARN_PARAMETERS),
        output:
            f"{RESULTS}/sealed/alice.json",
        log:
            f"{RESULTS}/logs/score_sealed.log",
        benchmark:
            f"{RESULTS}/benchmarks/score_sealed/score_sealed.tsv"
        conda:
            CONDA_ENV
        params:
            cli=FORCDECODE_1T,
            models=lambda wildcards, input: os.path.dirname(input.models[0]),
        shell:
            "{params.cli} learn sealed --models {params.models} --dataset {input.dataset} --sealed {input.sealed} "
            "--config {input.config} --out {output} > {log} 2>&1"

    rule posterior_sealed:
        """The joint posterior, frozen (recalibration included), on the sealed set: SBC, coverage, TARP, PIT,
        the derived combinations with their baselines."""
        input:
            config=rules.resolve_learning.output,
            dataset=rules.merge.output.h5,
            sealed=rules.merge_sealed.output.h5,
            model=rules.train_posterior.output.model,
        output:
            metrics=f"{RESULTS}/posterior/sealed.json",
            figure=report(
                f"{RESULTS}/posterior/figures/posterior_sealed.png",
                caption="../report/posterior_sealed.rst",
                category="2. Learning",
                labels={"name": "Posterior on the sealed set", "kind": "figure"},
            ),
        log:
            f"{RESULTS}/logs/posterior_sealed.log",
        benchmark:
            f"{RESULTS}/benchmarks/posterior_sealed/posterior_sealed.tsv"
        conda:
            CONDA_ENV
        threads: config["posterior"]["threads"]
        params:
            cli=FORCDECODE_1T,
        shell:
            "{params.cli} learn posterior-check --posterior {input.model} --dataset {input.sealed} "
            "--training-dataset {input.dataset} --config {input.config} --out {output.metrics} "
            "--figure {output.figure} --threads {threads} > {log} 2>&1"

    rule posterior_report:
        """results/posterior/metrics.json: the posterior's test figures with the sealed set's beside them."""
        input:
            metrics=rules.train_posterior.output.metrics,
            sealed=rules.posterior_sealed.output.metrics,
        output:
            f"{RESULTS}/posterior/metrics.json",
        log:
            f"{RESULTS}/logs/posterior_report.log",
        conda:
            CONDA_ENV
        params:
            cli=FORCDECODE,
        shell:
            "{params.cli} learn attach-sealed --metrics {input.metrics} --sealed {input.sealed} --out {output} 2> {log}"
