rule resolve_config:
    """The schema-validated configuration (defaults filled in), input of every stage."""
    output:
        f"{RESULTS}/config.json",
    params:
        cfg=json.dumps(config, sort_keys=True),
    log:
        f"{RESULTS}/logs/resolve_config.log",
    run:
        from forcdecode.dataset.io import write_json

        write_json(output[0], json.loads(params.cfg))
        with open(log[0], "w") as handle:
            handle.write(f"wrote {output[0]}\n")


rule draw:
    """Parameter draw for every sample, from (seed, sample id)."""
    input:
        config=rules.resolve_config.output,
    output:
        f"{RESULTS}/params.parquet",
    log:
        f"{RESULTS}/logs/draw.log",
    shell:
        "{FORCDECODE} dataset draw --config {input.config} --out {output} 2> {log}"
