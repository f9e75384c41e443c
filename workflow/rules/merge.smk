rule merge:
    """dataset.h5 (images, raw curves, parameters, provenance) and samples.parquet (every sample)."""
    input:
        config=rules.resolve_config.output,
        params=rules.draw.output,
        screens=SCREEN_CHUNKS,
        families=family_chunks,
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
        "--screens {input.screens} --families {input.families} --h5 {output.h5} --parquet {output.parquet} 2> {log}"
