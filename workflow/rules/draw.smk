rule resolve_config:
    """The schema-validated dataset configuration (defaults filled in), input of every stage. The
    learning and loop sections go to their own file, so changing them never re-simulates the dataset."""
    output:
        f"{RESULTS}/config.json",
    log:
        f"{RESULTS}/logs/resolve_config.log",
    params:
        # dataset_config leaves `realisations` out when it is 1 and `prior` when it is paper (the schema's
        # defaults): config.json, its hash and every family are then what they were before the keys
        # existed, so datasets and models already made stay valid and a running job reruns nothing
        cfg=json.dumps(
            dataset_config({k: v for k, v in config.items() if k not in STAGE_SECTIONS + OPTION_SECTIONS + SIZE_KEYS}),
            sort_keys=True,
        ),
    run:
        write_json(output[0], json.loads(params.cfg))
        Path(log[0]).write_text(f"wrote {output[0]}\n")


rule draw:
    """Parameter draw of one screening chunk's samples, from (seed, sample id)."""
    input:
        config=rules.resolve_config.output,
    output:
        f"{RESULTS}/params/chunk_{{chunk}}.parquet",
    log:
        f"{RESULTS}/logs/draw/chunk_{{chunk}}.log",
    benchmark:
        f"{RESULTS}/benchmarks/draw/chunk_{{chunk}}.tsv"
    conda:
        CONDA_ENV
    params:
        cli=FORCDECODE,
        chunk=lambda wildcards: int(wildcards.chunk),
    shell:
        "{params.cli} dataset draw --config {input.config} --chunk {params.chunk} --out {output} 2> {log}"


rule resolve_learning:
    """The learning and loop sections of the configuration (with the seed), input of the learning stages."""
    output:
        f"{RESULTS}/learning.json",
    log:
        f"{RESULTS}/logs/resolve_learning.log",
    params:
        cfg=json.dumps(
            {"seed": config["seed"], **{k: config[k] for k in STAGE_SECTIONS}},
            sort_keys=True,
        ),
    run:
        write_json(output[0], json.loads(params.cfg))
        Path(log[0]).write_text(f"wrote {output[0]}\n")
