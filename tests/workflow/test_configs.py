"""Every shipped configuration passes the workflow's schema; the paper scale trains the paper's network."""

from pathlib import Path

import pytest
import yaml
from snakemake.exceptions import WorkflowError
from snakemake.utils import validate

ROOT = Path(__file__).resolve().parents[2]
SCHEMA = str(ROOT / "workflow" / "schemas" / "config.schema.yaml")


@pytest.mark.parametrize("name", ["config.yaml", "paper.yaml", "test.yaml"])
def test_shipped_config_validates(name):
    config = yaml.safe_load((ROOT / "config" / name).read_text())
    validate(config, SCHEMA, set_default=True)
    assert config["learning"]["readout"] == "parabola"  # defaults filled in (no config sets it)


def test_paper_config_is_the_papers_training():
    learning = yaml.safe_load((ROOT / "config" / "paper.yaml").read_text())["learning"]
    assert (learning["model"], learning["lr"], learning["batch_size"]) == ("paper", 0.01, 500)


def test_a_wrong_learning_value_is_refused():
    config = yaml.safe_load((ROOT / "config" / "config.yaml").read_text())
    config["learning"]["model"] = "resnet"
    with pytest.raises(WorkflowError, match="resnet"):
        validate(config, SCHEMA)
