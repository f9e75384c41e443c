"""The posterior is trained by the main job (since 2026-11-28; issue 44 item 5), `snakemake
results/posterior/metrics.json` plans it without Alice and Bob, and its settings stay out of config.json and
learning.json (changing them re-simulates and retrains nothing else). Each run in a temporary
directory."""

import json
from pathlib import Path

from snakemake_runs import snakemake_process

ROOT = Path(__file__).resolve().parents[2]


def snakemake(workdir, *args, extra_config=()):
    return snakemake_process(workdir, *args, "--configfile", ROOT / "config" / "test.yaml", *extra_config)


def planned_jobs(text: str) -> dict:
    """The 'Job stats' table of a dry run: rule -> count."""
    lines = text.split("Job stats:", 1)[1].splitlines()[3:]
    jobs = {}
    for line in lines:
        parts = line.split()
        if len(parts) != 2 or parts[0] == "total":
            break
        jobs[parts[0]] = int(parts[1])
    return jobs


def test_the_main_job_trains_the_posterior_and_scores_it_on_the_sealed_set(tmp_path):
    run = snakemake(tmp_path, "-n", "results/posterior/metrics.json")
    assert run.returncode == 0, run.stderr[-3000:]
    jobs = planned_jobs(run.stdout)
    assert jobs.get("train_posterior") == 1 and "train_parameter" not in jobs, jobs
    assert jobs.get("posterior_sealed") == 1 and jobs.get("posterior_report") == 1, jobs
    run = snakemake(tmp_path, "-n")
    assert run.returncode == 0, run.stderr[-3000:]
    jobs = planned_jobs(run.stdout)
    assert jobs.get("train_posterior") == 1 and jobs.get("score_sealed") == 1 and jobs.get("merge_sealed") == 1, jobs


def test_posterior_settings_stay_out_of_the_stage_configs(tmp_path):
    (tmp_path / "posterior.yaml").write_text("posterior: {width: 8, epochs: 3}\n")
    run = snakemake(tmp_path, "results/config.json", "results/learning.json", extra_config=[tmp_path / "posterior.yaml"])
    assert run.returncode == 0, run.stderr[-3000:]
    dataset_cfg = json.loads((tmp_path / "results" / "config.json").read_text())
    learning_cfg = json.loads((tmp_path / "results" / "learning.json").read_text())
    assert "posterior" not in dataset_cfg and "posterior" not in learning_cfg
    assert "learning" in learning_cfg and "mesh" in dataset_cfg
