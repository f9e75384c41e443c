"""Text helpers shared by the readers: decoding, line splitting, strict number parsing."""

from __future__ import annotations

import re
from pathlib import Path

from .model import ForcFormatError

# A decimal number as instruments write it ("+1.234E-03", "0.5", "-.5", "6.6E-6"). Stricter than
# float(), which also takes "nan", "inf" and "1_000".
NUMBER = r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?"
_NUMBER_RE = re.compile(rf"\s*({NUMBER})\s*")


def read_lines(path: Path) -> tuple[list[str], bool]:
    """Decode a file (UTF-8, else Latin-1) and split it into lines.

    Splits on ``\\n`` only (stripping a trailing ``\\r``), so that Latin-1 bytes such as 0x85 do
    not count as line breaks and line numbers match what an editor shows. Returns the lines and
    whether the file ends with a line break.
    """
    data = path.read_bytes()
    if not data.strip():
        raise ForcFormatError(path, "expected a FORC measurement, the file is empty", 1)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        text = data.decode("latin-1")
    if text.startswith("\ufeff"):
        text = text[1:]
    ends_with_newline = text.endswith("\n")
    lines = text.split("\n")
    if ends_with_newline:
        lines.pop()
    return [line[:-1] if line.endswith("\r") else line for line in lines], ends_with_newline


def parse_number(text: str) -> float | None:
    """The number in ``text`` (surrounding blanks allowed), or None if it is not one."""
    match = _NUMBER_RE.fullmatch(text)
    return float(match.group(1)) if match else None


def header_value(text: str):
    """A header value: int or float where it is a number, None for N/A, else the stripped text."""
    text = text.strip()
    if text.upper() in {"N/A", "NA", ""}:
        return None
    match = _NUMBER_RE.fullmatch(text)
    if match:
        number = match.group(1)
        if re.fullmatch(r"[+-]?\d+", number):
            return int(number)
        return float(number)
    if len(text) >= 2 and text[0] == text[-1] == '"':
        return text[1:-1]
    return text


def header_int(header: dict, keys: tuple[str, ...]) -> int | None:
    """The first of ``keys`` present in ``header`` as a non-negative integer, else None."""
    for key in keys:
        value = header.get(key)
        if isinstance(value, int) and value >= 0:
            return value
        if isinstance(value, float) and value.is_integer() and value >= 0:
            return int(value)
    return None


def shorten(line: str, width: int = 60) -> str:
    """``line`` for an error message: repr, cut to ``width`` characters."""
    return repr(line if len(line) <= width else line[:width] + "...")
