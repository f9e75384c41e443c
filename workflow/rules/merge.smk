rule merge:
    """dataset.h5 (images, raw curves, parameters, provenance) and samples.parquet (every sample)."""
    input:
        config=rules.resolve_config.output,
        params=PARAM_CHUNKS,
        screens=SCREEN_CHUNKS,
        families=FAMILY_LISTS,
    output:
        h5=f"{RESULTS}/dataset.h5",
        parquet=f"{RESULTS}/samples.parquet",
    log:
        f"{RESULTS}/logs/merge.log",
    benchmark:
        f"{RESULTS}/benchmarks/merge/merge.tsv"
    conda:
        CONDA_ENV
    params:
        cli=FORCDECODE,
    shell:
        "{params.cli} dataset merge --config {input.config} --params {input.params} "
        "--screens {input.screens} --family-lists {input.families} --h5 {output.h5} --parquet {output.parquet} 2> {log}"
