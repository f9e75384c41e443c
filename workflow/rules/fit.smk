# Refinement of the posterior for one family by simulation of that film (forcdecode fit-step): one
# job per round, so that on a cluster each round is a job whose simulations use its cores. Not in
# `all`: `snakemake --configfile config/config.yaml FIT.yaml -- results/fit/NAME/fit.json`, FIT.yaml holding
# a `fit:` section (input, Ms_kA_m or sample_id, budget, round_size, workers, extend_prior, predictive_reference;
# the config schema).


rule fit_init:
    """Amortized posterior draws of the family and the disorder floor (4 re-simulations of the
    amortized median): the refinement's state before its first round."""
    input:
        config=rules.resolve_config.output,
        posterior=rules.train_posterior.output.model,
        data=FIT["input"] or [],
        reference=FIT["predictive_reference"] or [],
    output:
        f"{FIT_DIR}/round_0000.npz",
    log:
        f"{FIT_DIR}/logs/init.log",
    benchmark:
        f"{FIT_DIR}/benchmarks/init.tsv"
    conda:
        CONDA_ENV
    threads: FIT["workers"]
    params:
        cli=FORCDECODE_1T,
        which=FIT_WHICH,
        seed=config["seed"],
        budget=FIT["budget"],
        round_size=FIT["round_size"],
        extend_prior=FIT_EXTEND,
        check=FIT_CHECK,
    shell:
        "{params.cli} fit-step init {input.data:q} {params.which} --posterior {input.posterior} "
        "--config {input.config} --budget {params.budget} --round-size {params.round_size} --seed {params.seed} "
        "--workers {threads} {params.extend_prior} {params.check} --state {output} > {log} 2>&1"


rule fit_round:
    """One round: candidates from the current proposal, simulated on the film with common random
    numbers, weights and the tempering β updated."""
    input:
        config=rules.resolve_config.output,
        posterior=rules.train_posterior.output.model,
        state=lambda wildcards: f"{FIT_DIR}/round_{int(wildcards.r) - 1:04d}.npz",
    output:
        f"{FIT_DIR}/round_{{r}}.npz",
    log:
        f"{FIT_DIR}/logs/round_{{r}}.log",
    benchmark:
        f"{FIT_DIR}/benchmarks/round_{{r}}.tsv"
    wildcard_constraints:
        r="(?!0000)[0-9]{4}",
    conda:
        CONDA_ENV
    threads: FIT["workers"]
    params:
        cli=FORCDECODE_1T,
    shell:
        "{params.cli} fit-step round --posterior {input.posterior} --config {input.config} "
        "--state-in {input.state} --state-out {output} --workers {threads} > {log} 2>&1"


rule fit_report:
    """fit.json: amortized and refined medians, 68/90 % intervals, ESS and β per round; with
    fit.predictive_reference, the calibrated check's verdict and its figure."""
    input:
        state=f"{FIT_DIR}/round_{FIT_ROUNDS:04d}.npz",
        reference=FIT["predictive_reference"] or [],
    output:
        json=f"{FIT_DIR}/fit.json",
        figure=(
            report(
                f"{FIT_DIR}/predictive_check.png",
                caption="../report/predictive_check.rst",
                category="Refinement",
                labels={"name": f"{FIT_NAME}: check against validation", "kind": "figure"},
            )
            if FIT["predictive_reference"]
            else []
        ),
    log:
        f"{FIT_DIR}/logs/report.log",
    conda:
        CONDA_ENV
    params:
        cli=FORCDECODE_1T,
        check=FIT_CHECK,
    shell:
        "{params.cli} fit-step report --state {input.state} --out {output.json} {params.check} > {log} 2>&1"
