"""Atomic writes leave either the old file or the complete new one; JSON errors name the file."""

import json

import pandas as pd
import pytest

from forcdecode.core.errors import ConfigError, ForcdecodeError, InputFileError
from forcdecode.core.io import append_jsonl, atomic_path, read_config, read_json, write_json, write_parquet, write_text


def test_atomic_path_keeps_the_old_file_when_the_writer_fails(tmp_path):
    target = tmp_path / "sub" / "out.txt"
    write_text(target, "old")
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_text("half")
            raise RuntimeError("killed")
    assert target.read_text() == "old"
    assert [p.name for p in target.parent.iterdir()] == ["out.txt"]  # no temporary left behind


def test_writers_round_trip(tmp_path):
    write_json(tmp_path / "a.json", {"b": 1, "a": [1.5, None]})
    assert (tmp_path / "a.json").read_text() == '{\n  "a": [\n    1.5,\n    null\n  ],\n  "b": 1\n}\n'
    assert read_json(tmp_path / "a.json") == {"a": [1.5, None], "b": 1}
    frame = pd.DataFrame({"x": [1, 2], "y": [0.5, 0.25]})
    write_parquet(tmp_path / "f.parquet", frame)
    assert pd.read_parquet(tmp_path / "f.parquet").equals(frame)


def test_read_errors_name_the_path(tmp_path):
    with pytest.raises(InputFileError, match=r"absent\.json not found"):
        read_json(tmp_path / "absent.json")
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(InputFileError, match=r"bad\.json is not valid JSON"):
        read_json(bad)
    with pytest.raises(ConfigError, match=r"config file .*bad\.json is not valid JSON"):
        read_config(bad)
    (tmp_path / "list.json").write_text(json.dumps([1, 2]))
    with pytest.raises(ConfigError, match="mapping"):
        read_config(tmp_path / "list.json")
    assert issubclass(ConfigError, ForcdecodeError) and issubclass(ConfigError, ValueError)


def _append_many(path, tag, n):
    from forcdecode.core.io import append_jsonl

    for i in range(n):
        append_jsonl(path, {"tag": tag, "i": i, "pad": "x" * 30000})  # longer than Python's buffers


def test_append_jsonl_creates_the_file_and_keeps_lines_whole_across_processes(tmp_path):
    import multiprocessing

    path = tmp_path / "deep" / "rows.jsonl"
    append_jsonl(path, {"tag": "first", "value": float("nan")})
    context = multiprocessing.get_context("spawn")
    workers = [context.Process(target=_append_many, args=(path, tag, 200)) for tag in ("a", "b")]
    for w in workers:
        w.start()
    for w in workers:
        w.join()
    rows = [json.loads(line) for line in path.read_text().splitlines()]
    assert rows[0]["tag"] == "first" and len(rows) == 401
    for tag in ("a", "b"):
        assert [r["i"] for r in rows if r["tag"] == tag] == list(range(200))
