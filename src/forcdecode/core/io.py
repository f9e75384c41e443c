"""File helpers shared by every layer: atomic writes (a temporary file beside the target, then a
rename, so a killed job never leaves a half-written output that looks complete) and JSON reading
with errors that name the file."""

from __future__ import annotations

import json
import os
from contextlib import contextmanager
from pathlib import Path

from .errors import ConfigError, InputFileError


@contextmanager
def atomic_path(path: str | Path):
    """Yield a temporary path beside ``path``; on success it is renamed to ``path``, on error removed."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def write_json(path, obj) -> None:
    """Write ``obj`` as indented, key-sorted JSON, atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(obj, indent=2, sort_keys=True) + "\n")


def append_jsonl(path, obj, default=None) -> None:
    """Append ``obj`` as one JSON line to ``path`` (created with its folders): the resumable record of a
    long run, one line per finished item. The line goes out in one ``write`` on a descriptor opened with
    ``O_APPEND``, so on a local file system lines from processes that share the file (shards of one
    bench) do not interleave, long rows (tens of kB) included; a run killed between items loses nothing
    that was written."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    data = (json.dumps(obj, default=default) + "\n").encode()
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        written = os.write(fd, data)
        while written < len(data):  # a short write (a signal, a full disk): the rest, still appended
            written += os.write(fd, data[written:])
    finally:
        os.close(fd)


def write_text(path, text: str) -> None:
    """Write a text file atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(text)


def write_parquet(path, frame) -> None:
    """Write a pandas DataFrame (without its index) as Parquet, atomically."""
    with atomic_path(path) as tmp:
        frame.to_parquet(tmp, index=False)


def read_json(path, what: str = "JSON file", error: type = InputFileError):
    """The parsed content of a JSON file; a missing, unreadable or malformed file raises ``error``
    (:class:`InputFileError` by default, :class:`ConfigError` for configurations) naming the path."""
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise error(f"{what} {path} not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise error(f"cannot read {what} {path}: {exc}") from None
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise error(f"{what} {path} is not valid JSON: {exc}") from None


def read_config(path) -> dict:
    """The resolved (schema-validated) configuration written by the workflow's ``config`` rule
    (JSON); :class:`ConfigError` naming the file when it is missing or malformed."""
    cfg = read_json(path, what="config file", error=ConfigError)
    if not isinstance(cfg, dict):
        raise ConfigError(f"config file {path} does not hold a mapping")
    return cfg


__all__ = ["atomic_path", "write_json", "write_text", "write_parquet", "read_json", "read_config"]
