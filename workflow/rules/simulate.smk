rule simulate_family:
    """FORC families of one chunk of passing samples (failed samples are recorded, not dropped)."""
    input:
        config=rules.resolve_config.output,
        params=rules.draw.output,
        selection=f"{RESULTS}/screen/selection.json",
    output:
        f"{RESULTS}/families/chunk_{{chunk}}.h5",
    log:
        f"{RESULTS}/logs/families/chunk_{{chunk}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/simulate_family/chunk_{{chunk}}.tsv"
    conda:
        CONDA_ENV
    threads: 1
    resources:
        mem_mb=4000,
        runtime=600,
    params:
        cli=FORCDECODE_1T,
        chunk=lambda wildcards: int(wildcards.chunk),
    shell:
        "{params.cli} dataset simulate --config {input.config} --params {input.params} "
        "--selection {input.selection} --chunk {params.chunk} --out {output} 2> {log}"
