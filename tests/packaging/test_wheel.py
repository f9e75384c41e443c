"""The package works from a wheel: build it, install it (not editable) into a fresh virtual
environment, and from another directory read a real measured file, ask ``forcdecode loop`` for its
help, run the loop with the packaged default config, and load the packaged schema and configs.

The fresh environment reuses the dependencies already installed beside the running interpreter
(a directory of symlinks to them, minus forcdecode itself, put on its path by a .pth file): nothing
is downloaded, and forcdecode can only come from the wheel.
"""

import json
import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
MEASURED = ROOT.parent / "shared" / "data" / "measured"
SOURCES = ("pyproject.toml", "README.md", "src", "config", "workflow/schemas")


def _run(cmd, cwd, env, timeout=300):
    result = subprocess.run([str(c) for c in cmd], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert result.returncode == 0, f"{' '.join(map(str, cmd))}\n{result.stdout}\n{result.stderr}"
    return result


def _dependency_farm(target: Path) -> Path:
    """Symlinks to the current environment's installed distributions, forcdecode excluded."""
    target.mkdir()
    site = Path(sysconfig.get_paths()["purelib"])
    for entry in site.iterdir():
        name = entry.name.lower()
        if name.startswith(("forcdecode", "__editable__", "__pycache__")) or name.endswith(".pth"):
            continue
        (target / entry.name).symlink_to(entry)
    return target


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    base = tmp_path_factory.mktemp("wheel")
    source = base / "source"  # a copy: the build writes build/ and *.egg-info beside the sources
    for part in SOURCES:
        origin = ROOT / part
        if origin.is_dir():
            shutil.copytree(origin, source / part, symlinks=True,
                            ignore=shutil.ignore_patterns("__pycache__", "*.egg-info", "*.pyc"))
        else:
            (source / part).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(origin, source / part)
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV")}
    env["PIP_NO_INDEX"] = "1"
    env["PIP_DISABLE_PIP_VERSION_CHECK"] = "1"
    dist = base / "dist"
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", dist, source], base, env)
    wheel = next(dist.glob("forcdecode-*.whl"))
    venv = base / "venv"
    _run([sys.executable, "-m", "venv", "--without-pip", venv], base, env)
    python = venv / "bin" / "python"
    site = Path(_run([python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], base,
                     env).stdout.strip())
    (site / "zz_dependencies.pth").write_text(str(_dependency_farm(base / "dependencies")) + "\n")
    _run([python, "-m", "pip", "install", "--no-deps", "-q", wheel], base, env)
    elsewhere = base / "elsewhere"
    elsewhere.mkdir()
    return {"wheel": wheel, "venv": venv, "python": python, "site": site, "cwd": elsewhere, "env": env}


def test_the_wheel_holds_the_schema_and_the_default_configs(installed):
    import zipfile

    names = set(zipfile.ZipFile(installed["wheel"]).namelist())
    assert {"forcdecode/config/schemas/config.schema.yaml", "forcdecode/config/defaults/config.yaml",
            "forcdecode/config/defaults/paper.yaml", "forcdecode/config/defaults/test.yaml",
            "forcdecode/config/defaults/cluster.yaml",
            "forcdecode/core/streams.py", "forcdecode/micromag/build.py"} <= names
    # the packaged files are the repository's (one copy each)
    wheel = zipfile.ZipFile(installed["wheel"])
    assert wheel.read("forcdecode/config/schemas/config.schema.yaml") == \
        (ROOT / "workflow" / "schemas" / "config.schema.yaml").read_bytes()
    assert wheel.read("forcdecode/config/defaults/config.yaml") == (ROOT / "config" / "config.yaml").read_bytes()


def test_installed_package_loads_its_schema_and_configs(installed):
    probe = ("import json, forcdecode, forcdecode.config as c; "
             "print(json.dumps({'file': forcdecode.__file__, 'schema': str(c.SCHEMA_PATH), "
             "'exists': c.SCHEMA_PATH.is_file(), "
             "'seeds': {n: c.load_config(c.shipped_config(n))['seed'] for n in c.SHIPPED_CONFIGS}, "
             "'lr': c.defaults('learning')['lr']}))")
    out = json.loads(_run([installed["python"], "-c", probe], installed["cwd"], installed["env"]).stdout)
    assert out["file"].startswith(str(installed["site"]))  # from the wheel, not from the checkout
    assert out["schema"].startswith(str(installed["site"])) and out["exists"]
    assert set(out["seeds"]) == {"config", "cluster", "paper", "test"} and out["seeds"]["test"] == 7
    assert out["lr"] > 0


def test_read_and_loop_from_another_directory(installed):
    data = MEASURED / "UB199BF.frc"
    if not data.exists():
        if os.environ.get("CI") == "true":
            pytest.fail(f"{data} is absent (the measured files are required in CI)")
        pytest.skip(f"{data} is absent")
    forcdecode = installed["venv"] / "bin" / "forcdecode"
    summary = json.loads(_run([forcdecode, "read", data, "--json"], installed["cwd"], installed["env"]).stdout)
    assert summary["n_curves"] > 50 and summary["format"].startswith("micromag")
    assert "--Ms-sweep-kA-m" in _run([forcdecode, "loop", "--help"], installed["cwd"], installed["env"]).stdout
    # the loop with no --config uses the packaged config.yaml: this real file lies outside its ±1 T domain
    _run([forcdecode, "loop", data, "--out", "loop"], installed["cwd"], installed["env"])
    report = json.loads((installed["cwd"] / "loop" / "report.json").read_text())
    assert report["status"] == "out of domain" and report["in_domain"] is False


def test_the_wheel_ships_the_trained_models_and_stays_under_50_mb(installed):
    """Issue 60: a file decoded right after `pip install`: the shipped models come with the wheel."""
    size_mb = installed["wheel"].stat().st_size / 1e6
    assert size_mb < 50, f"the wheel is {size_mb:.1f} MB"
    out = _run([installed["python"], "-c", "from forcdecode.learn.shipped import read_manifest, resolve_models; "
                "d, line = resolve_models(None); read_manifest(d.parent); print(line)"],
               installed["cwd"], installed["env"]).stdout
    assert out.startswith("models: the shipped laptop default models"), out
    print(f"wheel {installed['wheel'].name}: {size_mb:.1f} MB")
