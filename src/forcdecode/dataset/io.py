"""Moved to :mod:`forcdecode.core.io`; this re-export stays until every caller imports from there."""

from ..core.io import atomic_path, read_config, read_json, write_json, write_parquet

__all__ = ["atomic_path", "read_config", "read_json", "write_json", "write_parquet"]
