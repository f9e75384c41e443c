"""One schema, one source of defaults: load_config fills and validates, a wrong key is refused with
its name and the file; the shipped configurations are package data and validate."""

import subprocess
import sys

import pytest
import yaml

from forcdecode.config import (CONFIGS_DIR, SCHEMA_PATH, SHIPPED_CONFIGS, defaults, load_config, schema,
                               shipped_config, validate_config)
from forcdecode.core.errors import ConfigError


def test_the_schema_is_the_workflows_file():
    """One file: the package's schema is workflow/schemas/config.schema.yaml (through a symlink in a
    checkout), and the configs are the repository's config/."""
    root = SCHEMA_PATH.resolve().parents[2]
    assert SCHEMA_PATH.resolve() == (root / "workflow" / "schemas" / "config.schema.yaml")
    assert CONFIGS_DIR.resolve() == root / "config"


def test_defaults_come_from_the_schema():
    learning = defaults("learning")
    node = yaml.safe_load(SCHEMA_PATH.read_text())["properties"]["learning"]["properties"]
    assert learning == {k: v["default"] for k, v in node.items() if "default" in v}
    assert defaults()["mesh"] == {"nx": 64, "ny": 64, "nz": 1, "dx_nm": 2.0, "dy_nm": 2.0, "dz_nm": 4.0}
    assert "n_samples" not in defaults()  # required, no default
    learning["lr"] = -1.0  # a fresh copy each call
    assert defaults("learning")["lr"] > 0 and schema()["properties"]["learning"]["properties"]["lr"]["default"] > 0
    with pytest.raises(KeyError, match="no configuration section 'nope'"):
        defaults("nope")


@pytest.mark.parametrize("name", SHIPPED_CONFIGS)
def test_shipped_configs_validate_with_defaults_filled(name):
    raw = yaml.safe_load(shipped_config(name).read_text())
    cfg = load_config(shipped_config(name))
    assert cfg["n_samples"] == raw["n_samples"]
    assert cfg["learning"]["readout"] == defaults("learning")["readout"]  # no shipped config sets it
    assert cfg["loop"]["n_figure_samples"] >= 1 and cfg["protocol"]["name"] in ("quasistatic", "llg")


def test_same_result_as_snakemakes_validate():
    from snakemake.utils import validate

    for name in SHIPPED_CONFIGS:
        ours = load_config(shipped_config(name))
        theirs = yaml.safe_load(shipped_config(name).read_text())
        validate(theirs, str(SCHEMA_PATH), set_default=True)
        assert ours == theirs, name


def test_a_wrong_config_names_the_key_and_the_file(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("n_samples: 4\nmesh: {nx: 1}\n")
    with pytest.raises(ConfigError, match=r"bad\.yaml: invalid value at mesh\.nx: 1 is less than the minimum of 2"):
        load_config(path)
    path.write_text("n_samples: 4\nlearning: {model: resnet}\n")
    with pytest.raises(ConfigError, match=r"learning\.model: 'resnet' is not one of"):
        load_config(path)
    path.write_text("n_samples: 4\ntypo_key: 1\n")
    with pytest.raises(ConfigError, match="typo_key"):
        load_config(path)
    path.write_text("seed: 3\n")
    with pytest.raises(ConfigError, match="'n_samples' is a required property"):
        load_config(path)
    path.write_text("n_samples: [unclosed\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_config(path)
    with pytest.raises(ConfigError, match="not found"):
        load_config(tmp_path / "absent.yaml")
    with pytest.raises(ConfigError, match="mapping"):
        validate_config([1, 2])


def test_loop_refuses_a_bad_config_with_exit_code_2(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("n_samples: 4\nfield: {B_max_T: -1}\n")
    frc = tmp_path / "x.frc"
    frc.write_text("garbage\n")
    result = subprocess.run([sys.executable, "-m", "forcdecode.cli", "loop", str(frc), "--out", str(tmp_path / "o"),
                             "--config", str(bad)], capture_output=True, text=True, timeout=120)
    assert result.returncode == 2
    assert result.stderr.startswith("error: config file") and "field.B_max_T" in result.stderr
    assert "Traceback" not in result.stderr
