"""The workflow as Snakemake's tools judge it: `snakemake --lint`, `snakefmt --check`, and the SLURM
profile's per-rule resources naming rules that exist. Each run in a temporary working directory."""

import subprocess
import sys
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[2]
SNAKEMAKE = [sys.executable, "-m", "snakemake", "--snakefile", str(ROOT / "Snakefile")]


def snakemake(workdir, *args):
    return subprocess.run([*SNAKEMAKE, "--directory", str(workdir), *args], cwd=workdir, capture_output=True,
                          text=True, timeout=300)


@pytest.mark.parametrize("config", ["test.yaml", "config.yaml", "cluster.yaml", "paper.yaml"])
def test_snakemake_lint_prints_no_lints(tmp_path, config):
    run = snakemake(tmp_path, "--configfile", str(ROOT / "config" / config), "--lint")
    text = run.stdout + run.stderr
    assert run.returncode == 0, text[-3000:]
    assert "Lints for" not in text and "Congratulations" in text, text[-3000:]


def test_snakefmt_check_passes():
    run = subprocess.run([sys.executable, "-m", "snakefmt", "--check", "--diff", "."], cwd=ROOT, capture_output=True,
                         text=True, timeout=120)
    assert run.returncode == 0, (run.stdout + run.stderr)[-3000:]
    assert "would be left unchanged" in run.stderr and "Snakefile" not in run.stdout


def workflow_rules(tmp_path) -> set[str]:
    """The rule names `snakemake --list-rules` prints (one per line, docstring after it, on stdout)."""
    run = snakemake(tmp_path, "--configfile", str(ROOT / "config" / "test.yaml"), "--list-rules")
    assert run.returncode == 0, run.stderr[-3000:]
    rules = {line.split(" ", 1)[0] for line in run.stdout.splitlines() if line and not line[0].isspace()}
    assert {"draw", "screen", "select", "simulate_family", "merge", "train_parameter", "closed_loop"} <= rules, rules
    return rules


def test_slurm_profile_names_the_workflows_rules(tmp_path):
    profile = yaml.safe_load((ROOT / "profiles" / "slurm" / "config.yaml").read_text())
    rules = workflow_rules(tmp_path)
    named = set(profile["set-resources"])
    arrays = profile.get("slurm-array-jobs", "")
    if arrays and arrays != "all":
        named |= {name.strip() for name in arrays.split(",")}
    assert named <= rules, f"profiles/slurm names rules the workflow does not define: {sorted(named - rules)}"
    # every rule that runs a simulation or a training has its Slurm request stated
    assert {"screen", "simulate_family", "train_parameter", "closed_loop"} <= named
    for profile_dir in (ROOT / "profiles").iterdir():  # any other profile's per-rule settings too
        other = yaml.safe_load((profile_dir / "config.yaml").read_text()) or {}
        for key in ("set-resources", "set-threads"):
            assert set(other.get(key) or {}) <= rules, (profile_dir.name, key)


def test_wildcards_are_constrained(tmp_path):
    config = ["--configfile", str(ROOT / "config" / "test.yaml"), "-n"]
    good = snakemake(tmp_path, *config, "results/screen/chunk_0001.parquet", "results/models/K_u.pt")
    assert good.returncode == 0, good.stderr[-3000:]
    for target in ("results/screen/chunk_1.parquet", "results/models/Ms.pt"):  # 4-digit chunks; learned parameters
        bad = snakemake(tmp_path, *config, target)
        text = bad.stdout + bad.stderr
        assert bad.returncode != 0 and "MissingRuleException" in text, (target, text[-2000:])


def test_slurm_profile_resource_expressions_evaluate_on_the_rules_inputs(tmp_path, evaluate_slurm_resource):
    """A string resource in profiles/slurm is a Python expression Snakemake evaluates per job with the
    job's `input`. A rule input given as another rule's output (`rules.resolve_config.output`) is a
    list, so `input.config` is a Namedlist, not a path: this ran only on a real Slurm in CI and broke
    there (TypeError at the first simulate_family job). Evaluated here the way Snakemake does it, on
    an input built the way Snakemake builds it, with a config.json asking for 3 realisations."""
    config = tmp_path / "config.json"
    config.write_text('{"realisations": 3}')

    def evaluate(text):
        return evaluate_slurm_resource(text, config)

    profile = yaml.safe_load((ROOT / "profiles" / "slurm" / "config.yaml").read_text())
    expressions = {(rule, name): value for rule, resources in profile["set-resources"].items()
                   for name, value in resources.items() if isinstance(value, str)}
    assert ("simulate_family", "runtime") in expressions
    for (rule, name), text in expressions.items():
        value = evaluate(text)
        assert not isinstance(value, str), (rule, name, value)
    assert evaluate(expressions[("simulate_family", "runtime")]) == 240 * 3
