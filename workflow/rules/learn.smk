LEARN_PARAMETERS = config["learning"]["parameters"]


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
    wildcard_constraints:
        parameter="|".join(LEARN_PARAMETERS),
    threads: config["learning"]["threads"]
    resources:
        mem_mb=4000 if config["learning"]["model"] == "small" else 16000,
        runtime=240,
    shell:
        "{ENV} {FORCDECODE} learn train --config {input.config} --dataset {input.dataset} --parameter {wildcards.parameter} "
        "--model {output.model} --predictions {output.predictions} --metrics {output.metrics} --threads {threads} 2> {log}"


rule evaluate:
    """metrics.json (test split) and the learning figures: Figure 3, Figure 5b-c, learning and retention curves."""
    input:
        metrics=expand(f"{RESULTS}/learn/{{parameter}}_metrics.json", parameter=LEARN_PARAMETERS),
        predictions=expand(f"{RESULTS}/learn/{{parameter}}_predictions.parquet", parameter=LEARN_PARAMETERS),
    output:
        metrics=f"{RESULTS}/metrics.json",
        table=f"{RESULTS}/metrics.md",
        figure3=f"{RESULTS}/figures/figure3.png",
        figure5bc=f"{RESULTS}/figures/figure5bc.png",
        learning_curve=f"{RESULTS}/figures/learning_curve.png",
        retention=f"{RESULTS}/figures/retention.png",
    log:
        f"{RESULTS}/logs/evaluate.log",
    shell:
        "{FORCDECODE} learn evaluate --metrics {input.metrics} --predictions {input.predictions} "
        "--out {output.metrics} --figures {RESULTS}/figures > {log} 2>&1"


rule closed_loop:
    """Closed loop on the simulated test set: re-simulate the predicted Hamiltonians (Figure 4), the
    observation-space error and its correlation with Bob's predicted error."""
    input:
        config=rules.resolve_config.output,
        learning=rules.resolve_learning.output,
        dataset=rules.merge.output.h5,
        predictions=expand(f"{RESULTS}/learn/{{parameter}}_predictions.parquet", parameter=LEARN_PARAMETERS),
    output:
        summary=f"{RESULTS}/closed_loop.json",
        table=f"{RESULTS}/closed_loop.parquet",
        figure4=f"{RESULTS}/figures/figure4.png",
        correlation=f"{RESULTS}/figures/closed_loop_vs_bob.png",
    log:
        f"{RESULTS}/logs/closed_loop.log",
    threads: 1
    resources:
        runtime=240,
    shell:
        "{ENV} {FORCDECODE} closed-loop --config {input.config} --learning {input.learning} --dataset {input.dataset} "
        "--predictions {input.predictions} --out {output.summary} --table {output.table} --figures {RESULTS}/figures 2> {log}"
