rule figure1:
    """Figure 1 of the paper: a family with one minor loop highlighted, and its 64x64 image."""
    input:
        rules.merge.output.h5,
    output:
        f"{RESULTS}/figures/figure1.png",
    log:
        f"{RESULTS}/logs/figure1.log",
    shell:
        "{FORCDECODE} dataset figure1 --dataset {input} --out {output} 2> {log}"
