checkpoint screen:
    """Saturate, sweep half the major loop, keep hysteretic samples (one job per chunk of samples). A
    checkpoint: its passing samples decide the chunk's family jobs."""
    input:
        config=rules.resolve_config.output,
        params=f"{RESULTS}/params/chunk_{{chunk}}.parquet",
    output:
        f"{RESULTS}/screen/chunk_{{chunk}}.parquet",
    log:
        f"{RESULTS}/logs/screen/chunk_{{chunk}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/screen/chunk_{{chunk}}.tsv"
    conda:
        CONDA_ENV
    threads: 1
    resources:
        mem_mb=2000,
        runtime=120,
    params:
        cli=FORCDECODE_1T,
        chunk=lambda wildcards: int(wildcards.chunk),
    shell:
        "{params.cli} dataset screen --config {input.config} --params {input.params} "
        "--chunk {params.chunk} --out {output} 2> {log}"


rule select:
    """The screening summary (pass rate, reasons); each chunk's family jobs follow from its own screen."""
    input:
        config=rules.resolve_config.output,
        screens=SCREEN_CHUNKS,
    output:
        f"{RESULTS}/screen/selection.json",
    log:
        f"{RESULTS}/logs/select.log",
    benchmark:
        f"{RESULTS}/benchmarks/select/select.tsv"
    conda:
        CONDA_ENV
    params:
        cli=FORCDECODE,
    shell:
        "{params.cli} dataset select --config {input.config} --screens {input.screens} --out {output} 2> {log}"
