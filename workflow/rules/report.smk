rule report_tables:
    """The metrics, the samples' outcomes and the closed loop's summary as HTML pages for the report."""
    input:
        metrics=rules.evaluate.output.table,
        samples=rules.merge.output.parquet,
        closed_loop=rules.closed_loop.output.summary,
    output:
        metrics=report(
            f"{RESULTS}/tables/metrics.html",
            caption="../report/metrics.rst",
            category="2. Learning",
            labels={"name": "Metrics on the test split", "kind": "table"},
        ),
        samples=report(
            f"{RESULTS}/tables/samples.html",
            caption="../report/samples.rst",
            category="1. Dataset",
            labels={"name": "Screening and family outcomes", "kind": "table"},
        ),
        closed_loop=report(
            f"{RESULTS}/tables/closed_loop.html",
            caption="../report/closed_loop.rst",
            category="3. Closed loop",
            labels={"name": "Closed-loop summary", "kind": "table"},
        ),
    log:
        f"{RESULTS}/logs/report_tables.log",
    benchmark:
        f"{RESULTS}/benchmarks/report_tables/report_tables.tsv"
    conda:
        CONDA_ENV
    script:
        "../scripts/report_tables.py"
