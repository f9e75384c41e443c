"""The realisation floor's size, studied on the laptop bench's dev rows without re-running the loop
(issue 59 item 4: "choose the floor size on the dev set").

Each row written since 2026-12-02 carries the loop's per-film null gains (``null_gain_per_film``: the
largest gain of every candidate on each effect-free film of the decoded Hamiltonian, mirrored). The
floor of the first k films is their maximum, so for k = 1 … 10 this re-judges every candidate of every
row against the floor of k films (``loop.effects.beats_null_gain``, the loop's margin) and prints:

- on controls: the fraction where some candidate beats its floor (a necessary condition for a false
  attribution: the loop can only name an effect that beats its floor);
- on effect cases: the fraction where the true class's candidate beats its floor (a necessary
  condition for detecting it).

A smaller floor costs less (each film is a family of the decoded Hamiltonian) and lets more through;
the choice is the smallest k whose control rate stays at the 10-film floor's.

    .venv/bin/python scripts/floor_size_study.py [ROWS.jsonl] [--margin 0.05]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from forcdecode.loop.effects import beats_null_gain
from forcdecode.loop.physics_effects import merge_null_gains

ROWS = Path(__file__).resolve().parents[1] / "docs/results/loop_bench/user/laptop-dev/cases.jsonl"


def floor_of(per_film: list[dict], k: int) -> dict:
    """The floor of the first ``k`` films: per candidate, the largest gain among them."""
    floor: dict = {}
    for gains in per_film[:k]:
        floor = merge_null_gains(floor, gains)
    return floor


def beats(row: dict, name: str, floor: dict, margin: float) -> bool:
    """Does candidate ``name`` of ``row`` beat ``floor`` (the loop's rule, from the row's records)?"""
    record = row["candidates"].get(name)
    before = row.get("heldout_rms_before")
    if record is None or name not in floor or not before or record.get("heldout_rms") is None:
        return False
    none_mse = before**2
    gain_mse = none_mse - record["heldout_rms"] ** 2
    return beats_null_gain(record["relative_gain"], gain_mse, none_mse, floor[name], margin)


def study(rows: list[dict], sizes, margin: float) -> list[str]:
    usable = [r for r in rows if r.get("null_gain_per_film")]
    controls = [r for r in usable if r["kind"] == "control"]
    effects = [r for r in usable if r["kind"] != "control" and r["class"] in r["candidates"]]
    lines = [f"{len(usable)} rows with per-film null gains ({len(controls)} controls, {len(effects)} in-library "
             f"effect cases); margin {margin}"]
    for k in sizes:
        any_control = sum(any(beats(r, n, floor_of(r["null_gain_per_film"], k), margin) for n in r["candidates"])
                          for r in controls)
        true_effect = sum(beats(r, r["class"], floor_of(r["null_gain_per_film"], k), margin) for r in effects)
        lines.append(f"k = {k:2d} films: controls with a candidate above its floor {any_control}/{len(controls)}; "
                     f"effect cases whose true candidate beats its floor {true_effect}/{len(effects)}")
    return lines


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("rows", nargs="?", default=str(ROWS))
    parser.add_argument("--margin", type=float, default=0.05, help="the loop's null margin (default 0.05)")
    args = parser.parse_args()
    rows = [json.loads(line) for line in Path(args.rows).read_text().splitlines() if line.strip()]
    for line in study(rows, (1, 2, 4, 6, 8, 10), args.margin):
        print(line)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
