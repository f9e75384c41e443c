"""The sealed test set cannot feed back into anything fitted (learn/sealed.py, workflow/rules/sealed.smk).

Read from the workflow's own graphs (dry runs, nothing executed): no fitting job has a sealed chunk among
its ancestors, and every rule downstream of the sealed merge only reports. A sealed range that overlaps
the training range stops the workflow before any job, naming both ranges."""

import re
from pathlib import Path

import pytest
from snakemake_runs import snakemake_process

ROOT = Path(__file__).resolve().parents[2]
# rules that fit a weight, a quantile, a calibration map, a threshold or a choice
FITTING = {"train_parameter", "train_posterior", "tune_posterior", "posterior_recalibrate", "closed_loop",
           "posterior_closed_loop", "merge", "select"}
# what may sit downstream of the sealed set: its own scoring and the reports that print it
REPORTING = {"merge_sealed", "score_sealed", "posterior_sealed", "posterior_report", "evaluate", "report_tables", "all"}


def graph(workdir, kind: str, config: str, *extra) -> tuple[dict, dict]:
    """(node -> label, node -> set of parent nodes) of ``snakemake --rulegraph`` or ``--dag``."""
    run = snakemake_process(workdir, "--configfile", ROOT / "config" / config, *extra, f"--{kind}", "--forceall")
    assert run.returncode == 0, run.stderr[-3000:]
    labels = {m[0]: m[1] for m in re.findall(r'^\s*(\d+)\[label = "([^"]*)"', run.stdout, re.M)}
    parents = {node: set() for node in labels}
    for parent, child in re.findall(r"^\s*(\d+) -> (\d+)", run.stdout, re.M):
        parents[child].add(parent)
    return labels, parents


def ancestors(node, parents) -> set:
    seen, todo = set(), [node]
    while todo:
        for parent in parents[todo.pop()]:
            if parent not in seen:
                seen.add(parent)
                todo.append(parent)
    return seen


@pytest.mark.parametrize("config", ["test.yaml", "config.yaml"])
def test_no_fitting_rule_reads_the_sealed_set(tmp_path, config):
    labels, parents = graph(tmp_path, "rulegraph", config)
    rule = {label: node for node, label in labels.items()}
    assert "merge_sealed" in rule and "score_sealed" in rule and "posterior_sealed" in rule
    downstream = {labels[n] for n in labels if rule["merge_sealed"] in ancestors(n, parents)}
    assert downstream <= REPORTING, downstream - REPORTING
    assert not downstream & FITTING


def test_no_fitting_job_has_a_sealed_chunk_upstream(tmp_path):
    labels, parents = graph(tmp_path, "dag", "test.yaml")
    chunk = {n: int(m.group(1)) for n, label in labels.items() if (m := re.search(r"chunk: (\d+)", label))}
    sealed_draws = {n for n, c in chunk.items() if labels[n].startswith("draw") and c >= 400 // 8}
    training_draws = {n for n, c in chunk.items() if labels[n].startswith("draw") and c < 400 // 8}
    assert len(sealed_draws) == 2 and len(training_draws) == 5  # 16 sealed ids, 40 training ids, 8 per chunk
    fitting = [n for n, label in labels.items() if label.split("\\n")[0] in FITTING]
    assert fitting
    for node in fitting:
        assert not ancestors(node, parents) & sealed_draws, labels[node]
    # and the sealed scoring does read them
    scoring = next(n for n, label in labels.items() if label.startswith("score_sealed"))
    assert sealed_draws <= ancestors(scoring, parents)


def test_an_overlapping_sealed_range_stops_before_any_job(tmp_path):
    (tmp_path / "overlap.yaml").write_text("sealed: {first_sample_id: 32, n_samples: 16}\n")
    run = snakemake_process(tmp_path, "--configfile", ROOT / "config" / "test.yaml", tmp_path / "overlap.yaml", "-n")
    assert run.returncode != 0
    assert "overlaps the training range" in run.stdout + run.stderr
