"""Fuzzing the readers with damaged versions of real (and synthetic) files.

Whatever the damage (lines deleted, duplicated or swapped, bytes corrupted, the file cut, numbers
replaced by garbage), ``read_forc`` either raises ForcFormatError or returns a self-consistent
data set; never any other exception.
"""

from __future__ import annotations

import os
import re
import tempfile
from functools import cache
from pathlib import Path

import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from forcdecode.measured import ForcFormatError, read_forc
from measured_fixtures import (DATA_DIR, plain_csv, qd_forc, shrink_irregular, shrink_lakeshore_csv,
                               shrink_micromag)
from test_measured_readers import assert_consistent

pytestmark = pytest.mark.skipif(not DATA_DIR.is_dir(), reason=f"{DATA_DIR} is absent")

FUZZ = settings(max_examples=100, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])

GARBAGE = [b"", b"abc", b"nan", b"inf", b"-inf", b"1e999", b"-", b"+", b"1.2.3", b"1_000",
           b"\x00", b"1e-999", b"99999999999", b"-0", b"\xb5", b",", b"\r", b'"', b"E", b"+.E1",
           b"0x1F", b"\xef\xbb\xbf", b"1e5", b"-3e4", b"0"]
_NUMBER = re.compile(rb"[+-]?\d+\.?\d*(?:[eE][+-]?\d+)?")


@cache
def small_sources() -> dict[str, bytes]:
    """Small valid files: real files cut to a few curves (counts patched), synthetic ones."""
    return {
        "micromag-0015": shrink_micromag(DATA_DIR / "MSM33-55-1_d330.forc", 6),
        "micromag-0015-cgs": shrink_micromag(DATA_DIR / "agm_cgs_0141327c.frc", 6),
        "micromag-0016": shrink_micromag(DATA_DIR / "MD00-2361.frc", 8),
        "micromag-irregular": shrink_irregular(DATA_DIR / "MSM33-53-1-d400_5.irforc", 4),
        "lakeshore8600-micromag": (DATA_DIR / "lakeshore8600_micromag_layout_excerpt.forc")
        .read_bytes(),
        "lakeshore8600-csv": shrink_lakeshore_csv(DATA_DIR / "B-9-3-85-87-FORC-1.5T.csv", 6),
        "qd-dat": qd_forc(6)["bytes"],
        "csv": plain_csv("SI"),
    }


SOURCE_NAMES = ["micromag-0015", "micromag-0015-cgs", "micromag-0016", "micromag-irregular",
                "lakeshore8600-micromag", "lakeshore8600-csv", "qd-dat", "csv"]


# A mutation is (kind, position, position, garbage): positions are fractions of the file so
# that hypothesis can shrink them independently of file length.
mutations = st.tuples(
    st.sampled_from(["delete_line", "delete_lines", "corrupt_byte", "truncate", "swap_number",
                     "duplicate_line", "swap_lines", "insert_blank"]),
    st.floats(0, 1, exclude_max=True), st.floats(0, 1, exclude_max=True),
    st.sampled_from(GARBAGE) | st.binary(min_size=1, max_size=3))


def mutate(data: bytes, kind: str, a: float, b: float, garbage: bytes) -> bytes:
    if not data:
        return data
    if kind == "corrupt_byte":
        position = int(a * len(data))
        return data[:position] + garbage[:1] + data[position + 1:]
    if kind == "truncate":
        return data[: int(a * len(data))]
    lines = data.split(b"\n")
    i, j = int(a * len(lines)), int(b * len(lines))
    if kind == "delete_line":
        del lines[i]
    elif kind == "delete_lines":
        del lines[min(i, j): max(i, j) + 1]
    elif kind == "swap_number":
        numbers = list(_NUMBER.finditer(lines[i]))
        if numbers:
            number = numbers[int(b * len(numbers))]
            lines[i] = lines[i][: number.start()] + garbage + lines[i][number.end():]
    elif kind == "duplicate_line":
        lines.insert(j, lines[i])
    elif kind == "swap_lines":
        lines[i], lines[j] = lines[j], lines[i]
    elif kind == "insert_blank":
        lines.insert(i, b"\r" if garbage[:1] == b"\r" else b"")
    return b"\n".join(lines)


def read_or_format_error(data: bytes, suffix: str, drift_correction: bool,
                         allow_incomplete: bool = False) -> None:
    handle, name = tempfile.mkstemp(suffix=suffix)
    try:
        with os.fdopen(handle, "wb") as file:
            file.write(data)
        try:
            measurement = read_forc(Path(name), drift_correction=drift_correction,
                                    allow_incomplete=allow_incomplete)
        except ForcFormatError as error:
            assert name in str(error)
            assert error.line is not None and f"line {error.line}" in str(error), str(error)
            event("ForcFormatError")
            return
        event("read")
        assert_consistent(measurement, require_complete=not allow_incomplete)
    finally:
        os.unlink(name)


@FUZZ
@given(source=st.sampled_from(["micromag-0015", "micromag-0015-cgs", "micromag-0016",
                               "micromag-irregular", "lakeshore8600-micromag"]),
       changes=st.lists(mutations, min_size=1, max_size=3), drift_correction=st.booleans())
def test_fuzz_micromag_layouts(source, changes, drift_correction):
    data = small_sources()[source]
    for change in changes:
        data = mutate(data, *change)
    read_or_format_error(data, ".frc", drift_correction)


@FUZZ
@given(source=st.sampled_from(["lakeshore8600-csv", "qd-dat", "csv"]),
       changes=st.lists(mutations, min_size=1, max_size=3), drift_correction=st.booleans())
def test_fuzz_csv_layouts(source, changes, drift_correction):
    data = small_sources()[source]
    for change in changes:
        data = mutate(data, *change)
    read_or_format_error(data, ".csv", drift_correction)


@settings(FUZZ, max_examples=40)
@given(name=st.sampled_from(["MSM33-55-1_d330.forc", "UB199BF.frc", "agm_cgs_0141327c.frc",
                             "MD00-2361.frc", "MSM33-53-1-d400_5.irforc"]),
       change=mutations)
def test_fuzz_full_real_files(name, change):
    data = mutate(_real_bytes(name), *change)
    read_or_format_error(data, ".frc", drift_correction=True)


@settings(FUZZ, max_examples=60)
@given(source=st.sampled_from(SOURCE_NAMES),
       changes=st.lists(mutations, min_size=1, max_size=2))
def test_fuzz_allow_incomplete_never_crashes(source, changes):
    data = small_sources()[source]
    for change in changes:
        data = mutate(data, *change)
    read_or_format_error(data, ".dat", drift_correction=True, allow_incomplete=True)


@cache
def _real_bytes(name: str) -> bytes:
    return (DATA_DIR / name).read_bytes()
