rule simulate_family:
    """FORC families of one chunk of passing samples (failed samples are recorded, not dropped); with
    `realisations: R` each is the mean over R disorder realisations."""
    input:
        config=rules.resolve_config.output,
        params=f"{RESULTS}/params/chunk_{{chunk}}.parquet",
        screen=f"{RESULTS}/screen/chunk_{{chunk}}.parquet",
    output:
        f"{RESULTS}/families/chunk_{{chunk}}_{{part}}.h5",
    log:
        f"{RESULTS}/logs/families/chunk_{{chunk}}_{{part}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/simulate_family/chunk_{{chunk}}_{{part}}.tsv"
    conda:
        CONDA_ENV
    threads: 1
    # a family of R disorder realisations costs R families (run one after another: the memory stays)
    resources:
        mem_mb=4000,
        runtime=600 * config["realisations"],
    params:
        cli=FORCDECODE_1T,
        chunk=lambda wildcards: int(wildcards.chunk),
        part=lambda wildcards: int(wildcards.part),
    shell:
        "{params.cli} dataset simulate --config {input.config} --params {input.params} "
        "--screen {input.screen} --chunk {params.chunk} --part {params.part} --out {output} 2> {log}"


rule families_of_chunk:
    """The family files of one screening chunk, listed once they exist (the checkpoint's aggregate)."""
    input:
        chunk_family_parts,
    output:
        f"{RESULTS}/families/chunk_{{chunk}}.json",
    log:
        f"{RESULTS}/logs/families/chunk_{{chunk}}_list.log",
    run:
        write_json(output[0], {"chunk": wildcards.chunk, "families": list(input)})
        Path(log[0]).write_text(f"{len(input)} family files\n")
