rule screen:
    """Saturate, sweep half the major loop, keep hysteretic samples (one job per chunk of samples)."""
    input:
        config=rules.resolve_config.output,
        params=rules.draw.output,
    output:
        f"{RESULTS}/screen/chunk_{{chunk}}.parquet",
    log:
        f"{RESULTS}/logs/screen/chunk_{{chunk}}.log",
    threads: 1
    resources:
        mem_mb=2000,
        runtime=120,
    shell:
        "{ENV} {FORCDECODE} dataset screen --config {input.config} --params {input.params} "
        "--chunk $((10#{wildcards.chunk})) --out {output} 2> {log}"


checkpoint select:
    """Aggregate the screening: which samples get a FORC family, in which chunk."""
    input:
        config=rules.resolve_config.output,
        screens=SCREEN_CHUNKS,
    output:
        f"{RESULTS}/screen/selection.json",
    log:
        f"{RESULTS}/logs/select.log",
    shell:
        "{FORCDECODE} dataset select --config {input.config} --screens {input.screens} --out {output} 2> {log}"
