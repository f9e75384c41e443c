"""Library code raises typed errors; only the command line turns them into ``error: ...`` and exit
code 2. No module of the package raises SystemExit."""

import ast
import json
from pathlib import Path

import numpy as np

from forcdecode.cli import main

PACKAGE = Path(__file__).resolve().parents[2] / "src" / "forcdecode"


def test_no_library_module_raises_system_exit():
    offenders = []
    for path in PACKAGE.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Raise) and node.exc is not None:
                target = node.exc.func if isinstance(node.exc, ast.Call) else node.exc
                if isinstance(target, ast.Name) and target.id == "SystemExit":
                    offenders.append(f"{path.relative_to(PACKAGE)}:{node.lineno}")
    assert not offenders, offenders


def test_missing_models_exit_2(tmp_path, capsys):
    image = tmp_path / "image.npy"
    np.save(image, np.zeros((16, 16), np.uint8))
    assert main(["predict", str(image), "--Ms-kA-m", "800", "--models", str(tmp_path / "none")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: no trained model in") and "Traceback" not in err


def test_part_not_in_chunk_exit_2(tmp_path, capsys):
    (tmp_path / "config.json").write_text(json.dumps({"seed": 1, "family_chunk_size": 2, "field": {"n_fields": 4}}))
    import pandas as pd

    pd.DataFrame({"sample_id": [0, 1], "screen_status": ["passed", "rejected"]}).to_parquet(tmp_path / "screen.parquet")
    pd.DataFrame({"sample_id": [0], "Ms": [1e6]}).to_parquet(tmp_path / "params.parquet")
    code = main(["dataset", "simulate", "--config", str(tmp_path / "config.json"), "--params",
                 str(tmp_path / "params.parquet"), "--screen", str(tmp_path / "screen.parquet"), "--chunk", "0",
                 "--part", "5", "--out", str(tmp_path / "family.h5")])
    assert code == 2
    assert capsys.readouterr().err.strip() == (f"error: part 5 is not among the 1 family parts of "
                                               f"{tmp_path / 'screen.parquet'}")
    assert not (tmp_path / "family.h5").exists()


def test_bad_config_json_exit_2(tmp_path, capsys):
    (tmp_path / "config.json").write_text("{")
    assert main(["dataset", "draw", "--config", str(tmp_path / "config.json"), "--out", str(tmp_path / "p.parquet")]) == 2
    assert "is not valid JSON" in capsys.readouterr().err


def test_posterior_tune_candidates_that_are_not_a_list_of_settings_exit_2(tmp_path, capsys):
    (tmp_path / "learning.json").write_text(json.dumps({"seed": 1}))
    for bad, says in (("[oops", "not a JSON list"), ('{"coordinates": "box"}', "non-empty JSON list"), ("[]", "non-empty")):
        code = main(["learn", "posterior-tune", "--config", str(tmp_path / "learning.json"), "--dataset",
                     str(tmp_path / "none.h5"), "--out", str(tmp_path / "o.json"), "--candidates", bad])
        err = capsys.readouterr().err
        assert code == 2 and err.startswith("error: --candidates") and says in err, err
