rule figure1:
    """Figure 1 of the paper: a family with one minor loop highlighted, and its 64x64 image."""
    input:
        rules.merge.output.h5,
    output:
        report(
            f"{RESULTS}/figures/figure1.png",
            caption="../report/figure1.rst",
            category="1. Dataset",
            labels={"name": "Figure 1: a FORC family and its image", "kind": "figure"},
        ),
    log:
        f"{RESULTS}/logs/figure1.log",
    benchmark:
        f"{RESULTS}/benchmarks/figure1/figure1.tsv"
    conda:
        CONDA_ENV
    params:
        cli=FORCDECODE,
    shell:
        "{params.cli} dataset figure1 --dataset {input} --out {output} 2> {log}"
