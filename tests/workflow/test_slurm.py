"""Integration test: the SLURM profile (profiles/slurm) against a real single-node Slurm.

The test starts Slurm on this machine with workflow/scripts/slurm_single_node.sh (installs the
Debian packages slurm-wlm and munge on first use), then runs Snakemake with
``--profile profiles/slurm`` and checks that the jobs really went through Slurm.

Needs root (it installs packages and starts daemons), so it runs only when asked:

    FORCDECODE_SLURM_TEST=1 .venv/bin/python -m pytest tests/workflow/test_slurm.py -q

(.ci/run sets FORCDECODE_SLURM_TEST=1; without it the test is skipped, with it on a machine that
cannot run it, it fails.)

By default it runs a tiny self-contained workflow written into a tmp dir (4 parallel chunk jobs,
one aggregate, one summary). To run the project's real workflow instead, change the parameters in
the "what to run" block below (see the example there).
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
SETUP_SCRIPT = REPO / "workflow" / "scripts" / "slurm_single_node.sh"
PROFILE = REPO / "profiles" / "slurm"

# ---------------------------------------------------------------------------------------------
# What to run. Paths may be absolute or relative to the repository root; "{tmp}" in any string
# is replaced by the test's tmp_path.
#
# Tiny self-contained workflow (default): SNAKEFILE = None writes TINY_SNAKEFILE to {tmp}.
# For the project's real workflow with its tiny config, e.g.:
#   SNAKEFILE = REPO / "Snakefile"
#   WORKDIR = "{tmp}"                   # run dir (--directory); keeps results/ out of the repo
#   SNAKEMAKE_ARGS = [*COMMON_ARGS, "--configfile", str(REPO / "config" / "test.yaml")]
#   EXPECTED_OUTPUTS = ["results/..."]  # files that must exist afterwards (relative to WORKDIR)
# Per-job requests must fit the test node (2 CPUs, <= 8000 MB; the profile caps threads at
# `cores: 2`); larger requests are rejected at submission (EnforcePartLimits), not left pending.
#   EXPECTED_RULES = {"draw", "screen", "simulate_family", ...}  # rules that must have gone via Slurm
#   CHECK_TINY_OUTPUTS = False
# ---------------------------------------------------------------------------------------------
COMMON_ARGS = [
    "--profile", str(PROFILE),
    # Do not also pick up profiles/default (it would override profile keys per key).
    "--workflow-profile", "none",
    # Keep the per-job Slurm logs of successful jobs too, so the test can look at them.
    "--slurm-keep-successful-logs",
]
# The project's real workflow on its tiny CI config, run in a temporary directory.
SNAKEFILE: Path | None = REPO / "Snakefile"
WORKDIR: Path | str = "{tmp}"
SNAKEMAKE_ARGS: list[str] = [*COMMON_ARGS, "--configfile", str(REPO / "config" / "test.yaml")]
EXPECTED_OUTPUTS: list[str] = ["results/dataset.h5", "results/samples.parquet", "results/figures/figure1.png",
                               "results/screen/selection.json", "results/metrics.json", "results/models/D.pt",
                               "results/closed_loop.json", "results/tables/metrics.html",
                               "results/benchmarks/train_parameter/D.tsv"]
EXPECTED_RULES: set[str] = {"resolve_config", "draw", "screen", "select", "simulate_family", "merge", "figure1",
                            "resolve_learning", "train_parameter", "evaluate", "closed_loop", "report_tables"}
CHECK_TINY_OUTPUTS = False

SETUP_TIMEOUT_S = 900      # apt-get install on a fresh machine + daemon start
SNAKEMAKE_TIMEOUT_S = 600  # the whole Snakemake run through Slurm

TINY_SNAKEFILE = textwrap.dedent(
    r'''
    # Tiny workflow for the SLURM integration test: 4 chunk jobs in parallel, 1 aggregate, 1 summary.
    CHUNKS = range(4)


    rule summary:
        default_target: True
        input:
            total="results/total.txt",
        output:
            "results/summary.txt",
        log:
            "logs/summary.log",
        shell:
            'echo "summary SLURM_JOB_ID=${{SLURM_JOB_ID:-none}}" > {log} 2>&1; '
            '(echo "total $(cat {input.total})"; echo "job ${{SLURM_JOB_ID:-none}}") > {output}'


    rule aggregate:
        input:
            expand("results/chunks/chunk_{i}.txt", i=CHUNKS),
        output:
            "results/total.txt",
        log:
            "logs/aggregate.log",
        shell:
            'echo "aggregate SLURM_JOB_ID=${{SLURM_JOB_ID:-none}}" > {log} 2>&1; '
            "awk '/^value/ {{s += $2}} END {{print s}}' {input} > {output}"


    rule chunk:
        output:
            "results/chunks/chunk_{i}.txt",
        log:
            "logs/chunk_{i}.log",
        threads: 1
        resources:
            mem_mb=500,
            runtime=5,
        shell:
            'echo "chunk {wildcards.i} on $(hostname) SLURM_JOB_ID=${{SLURM_JOB_ID:-none}}" > {log} 2>&1; '
            "start=$(date +%s.%N); sleep 3; "
            '(echo "value $(( ({wildcards.i} + 1) * 10 ))"; '
            'echo "job ${{SLURM_JOB_ID:-none}}"; echo "start $start"; echo "end $(date +%s.%N)") > {output}'
    '''
)

# Runs only when asked (it installs packages as root and starts daemons): FORCDECODE_SLURM_TEST=1,
# which .ci/run sets. Asked for on a machine that cannot run it, it fails rather than skips.
ASKED = os.environ.get("FORCDECODE_SLURM_TEST") == "1"
pytestmark = [
    pytest.mark.slurm,
    pytest.mark.skipif(not ASKED, reason="Slurm integration test: set FORCDECODE_SLURM_TEST=1 to run it"),
]


def _cannot_run() -> str | None:
    if not hasattr(os, "geteuid") or os.geteuid() != 0:
        return "needs root: installs slurm-wlm/munge and starts the Slurm daemons"
    if shutil.which("slurmctld") is None and shutil.which("apt-get") is None:
        return "Slurm is not installed and apt-get is unavailable to install it"
    return None


def _sub(value, tmp: Path) -> str:
    """Replace {tmp} in a parameter by the test's tmp_path."""
    return str(value).replace("{tmp}", str(tmp))


def _resolve(value, tmp: Path) -> Path:
    """A path parameter: {tmp} substituted, relative paths taken relative to the repository."""
    p = Path(_sub(value, tmp))
    return p if p.is_absolute() else REPO / p


def _tail(text: str, n: int = 200) -> str:
    lines = text.splitlines()
    return "\n".join(lines[-n:])


@pytest.fixture(scope="module")
def slurm_cluster():
    """Install (if needed) and start the single-node Slurm; leave it running afterwards."""
    reason = _cannot_run()
    if reason:
        pytest.fail(f"FORCDECODE_SLURM_TEST=1 but this machine cannot run the Slurm test: {reason}", pytrace=False)
    t0 = time.monotonic()
    # without the thread caps other tests leave in the environment (nproc obeys OMP_NUM_THREADS:
    # a 1-CPU node then refuses the 2-thread rules)
    env = {k: v for k, v in os.environ.items() if k not in ("OMP_NUM_THREADS", "OMP_THREAD_LIMIT")}
    proc = subprocess.run(
        ["bash", str(SETUP_SCRIPT), "start"],
        capture_output=True,
        text=True,
        timeout=SETUP_TIMEOUT_S,
        env=env,
    )
    elapsed = time.monotonic() - t0
    print(f"\n[slurm setup: {elapsed:.1f} s]\n{proc.stderr}{proc.stdout}")
    if proc.returncode != 0:
        pytest.fail(
            f"{SETUP_SCRIPT.name} failed (rc={proc.returncode}) after {elapsed:.1f} s:\n"
            f"--- stdout ---\n{proc.stdout}\n--- stderr ---\n{proc.stderr}",
            pytrace=False,
        )
    sinfo = subprocess.run(["sinfo", "-h", "-N", "-o", "%N %T %c %m"], capture_output=True, text=True)
    return {"setup_s": elapsed, "sinfo": sinfo.stdout.strip()}


def _scontrol_job(jobid: str) -> dict[str, str]:
    out = subprocess.run(
        ["scontrol", "-o", "show", "job", jobid], capture_output=True, text=True, timeout=30
    ).stdout
    return dict(re.findall(r"(\w+)=(\S*)", out))


def _run_jobs(run_id: str) -> dict[str, tuple[str, str]]:
    """Slurm jobs (and array tasks) named run_id: {jobid: (state, rule)} from squeue."""
    out = subprocess.run(
        ["squeue", "-h", "-t", "all", f"--name={run_id}", "-o", "%i|%T|%k"],
        capture_output=True, text=True, timeout=30,
    ).stdout
    jobs = {}
    for line in out.splitlines():
        jobid, state, comment = line.split("|", 2)
        m = re.match(r"rule_(.+?)(?:_wildcards_.*)?$", comment)
        jobs[jobid] = (state, m.group(1) if m else comment)
    return jobs


def _covers(job_names: set[str], rule: str) -> bool:
    """Did `rule` run as (part of) one of these Slurm jobs? A plain job is named after its rule;
    a group job `<groupid>_<rule1>_<rule2>...` (sorted rule names)."""
    return any(name == rule or f"_{rule}_" in f"_{name}_" for name in job_names)


def test_profile_runs_workflow_through_slurm(slurm_cluster, tmp_path):
    workdir = _resolve(WORKDIR, tmp_path)
    workdir.mkdir(parents=True, exist_ok=True)
    if SNAKEFILE is None:
        snakefile = workdir / "Snakefile"
        snakefile.write_text(TINY_SNAKEFILE)
    else:
        snakefile = _resolve(SNAKEFILE, tmp_path)

    # Jobs inside Slurm start `python -m snakemake` from this interpreter's environment: make sure
    # its bin/ comes first on PATH (sbatch exports the environment to the job).
    env = dict(os.environ)
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    env.pop("SLURM_JOB_ID", None)

    cmd = [
        sys.executable, "-m", "snakemake",
        "--snakefile", str(snakefile),
        "--directory", str(workdir),
        *[_sub(a, tmp_path) for a in SNAKEMAKE_ARGS],
    ]
    print("snakemake command:", " ".join(cmd))
    t0 = time.monotonic()
    try:
        proc = subprocess.run(
            cmd, cwd=workdir, env=env, capture_output=True, text=True, timeout=SNAKEMAKE_TIMEOUT_S
        )
    except subprocess.TimeoutExpired as exc:
        out = (exc.stdout or b"").decode(errors="replace") if isinstance(exc.stdout, bytes) else (exc.stdout or "")
        err = (exc.stderr or b"").decode(errors="replace") if isinstance(exc.stderr, bytes) else (exc.stderr or "")
        queue = subprocess.run(["squeue", "-t", "all"], capture_output=True, text=True).stdout
        m = re.search(r"SLURM run ID: (\S+)", out + err)
        if m:  # do not leave this run's jobs in the queue
            subprocess.run(["scancel", f"--name={m.group(1)}"], capture_output=True)
        pytest.fail(
            f"snakemake did not finish within {SNAKEMAKE_TIMEOUT_S} s.\n--- squeue -t all ---\n{queue}\n"
            f"--- snakemake output (tail) ---\n{_tail(out + err)}",
            pytrace=False,
        )
    elapsed = time.monotonic() - t0
    output = proc.stdout + proc.stderr
    print(f"[snakemake through Slurm: {elapsed:.1f} s, setup was {slurm_cluster['setup_s']:.1f} s]")

    def fail(msg: str):
        queue = subprocess.run(["squeue", "-t", "all"], capture_output=True, text=True).stdout
        pytest.fail(
            f"{msg}\n--- squeue -t all ---\n{queue}\n--- snakemake output (tail) ---\n{_tail(output)}",
            pytrace=False,
        )

    if proc.returncode != 0:
        fail(f"snakemake exited with {proc.returncode} after {elapsed:.1f} s")
    if not re.search(r"\(100%\) done", output):
        fail("snakemake did not report '(100%) done'")

    # The outputs exist.
    missing = [p for p in EXPECTED_OUTPUTS if not (workdir / p).is_file()]
    if missing:
        fail(f"missing outputs: {missing}")

    # The jobs went through Slurm: Snakemake says so, the plugin wrote per-job Slurm logs, and
    # slurmctld still lists the run's jobs (MinJobAge=3600) as COMPLETED. Plain jobs and array
    # tasks (`slurm-array-jobs`) both count.
    m = re.search(r"SLURM run ID: (\S+)", output)
    if not m:
        fail("no 'SLURM run ID' in the output: did Snakemake use the slurm executor?")
    run_id = m.group(1)
    if not re.search(r"submitted (with SLURM jobid|array job)", output, re.I):
        fail("no submitted Slurm jobs in the output: did the jobs run locally?")
    slurm_jobs = _run_jobs(run_id)
    if not slurm_jobs:
        fail(f"squeue lists no jobs named {run_id} (MinJobAge too short?)")
    not_done = {j: (state, rule) for j, (state, rule) in slurm_jobs.items() if state != "COMPLETED"}
    if not_done:
        fail(f"Slurm jobs of this run not COMPLETED according to squeue: {not_done}")
    names_in_slurm = {name for _, name in slurm_jobs.values()}
    missing_rules = {r for r in EXPECTED_RULES if not _covers(names_in_slurm, r)}
    if missing_rules:
        fail(f"rules {sorted(missing_rules)} did not run as Slurm jobs; squeue: {slurm_jobs}")
    logdir = workdir / ".snakemake" / "slurm_logs"
    names_with_logs = {
        re.sub(r"^(rule|group)_", "", p.relative_to(logdir).parts[0]) for p in logdir.rglob("*.log")
    }
    missing_logs = {r for r in EXPECTED_RULES if not _covers(names_with_logs, r)}
    if missing_logs:
        fail(f"no Slurm logs under {logdir} for rules {sorted(missing_logs)}")
    print(f"Slurm jobs of run {run_id}: {slurm_jobs}")

    if CHECK_TINY_OUTPUTS:
        chunk_jobs = set()
        for i in range(4):
            text = (workdir / f"results/chunks/chunk_{i}.txt").read_text()
            assert f"value {(i + 1) * 10}" in text
            job = re.search(r"^job (\S+)$", text, re.M).group(1)
            assert job != "none", f"chunk {i} did not run inside a Slurm job:\n{text}"
            info = _scontrol_job(job)
            assert info.get("JobName") == run_id, f"chunk {i}: Slurm job {job} is not from this run: {info}"
            assert info.get("JobState") == "COMPLETED", info
            assert info.get("Comment", "").startswith("rule_chunk"), info
            chunk_jobs.add(job)
        assert len(chunk_jobs) == 4, f"the 4 chunks should be 4 Slurm jobs, got {chunk_jobs}"
        assert (workdir / "results/total.txt").read_text().strip() == "100"
        summary = (workdir / "results/summary.txt").read_text()
        assert "total 100" in summary
        for name in ["summary", "aggregate"] + [f"chunk_{i}" for i in range(4)]:
            log = (workdir / f"logs/{name}.log").read_text()
            assert "SLURM_JOB_ID=" in log and "SLURM_JOB_ID=none" not in log, log
