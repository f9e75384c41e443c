"""The answer a user reads, typed: ``Estimate`` (one parameter or derived combination) and ``Prediction``
(the decoded Hamiltonian: M_s, the parameters, the combinations and the answer's notes), with one renderer,
``answer_table``, that `predict`, `loop` (its summary and report.md) and the report pages share.

The JSON a command writes stays the dict ``learn.answer`` builds (``Prediction.from_dict`` reads it, and
``Estimate.to_dict`` is its entry); the types replace the ``isinstance(entry, dict) and "value" in entry``
filters with named fields. Values are SI (units from ``core.parameters.UNITS`` or the combination's own).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from ..core.parameters import UNITS

PRIOR_ONLY = "not read from the image: prior only"
"""What a quantity the image does not inform prints instead of a number."""


def _pair(value) -> tuple | None:
    return None if value is None else (float(value[0]) if value[0] is not None else math.nan,
                                       float(value[1]) if value[1] is not None else math.nan)


@dataclass(frozen=True)
class Estimate:
    """One decoded quantity: ``value`` (SI; None where undefined) with its 68 and 90 % intervals, its unit,
    whether it is read from the image (on average over the prior, ``read_from_image``: True, False = prior
    only, None = unknown) and for this file (``read_for_this_file``), why (``basis``, ``per_file_basis``),
    and where it is prior only the prior's range. ``entry``: the dict it was read from (every other field)."""

    name: str
    kind: str  # "parameter" or "combination"
    value: float | None
    unit: str
    interval_68: tuple | None = None
    interval_90: tuple | None = None
    read_from_image: bool | None = None
    read_for_this_file: bool | None = None
    basis: str | None = None
    per_file_basis: str | None = None
    prior_range: tuple | None = None
    bob_error_normalized: float | None = None
    defined_fraction: float | None = None
    entry: dict = field(default_factory=dict, repr=False, compare=False)

    @classmethod
    def from_entry(cls, name: str, entry: dict, kind: str = "parameter") -> "Estimate":
        value = entry.get("value")
        return cls(name=name, kind=kind, value=None if value is None else float(value),
                   unit=entry.get("unit") or UNITS.get(name, ""), interval_68=_pair(entry.get("interval_68")),
                   interval_90=_pair(entry.get("interval_90")), read_from_image=entry.get("read_from_image"),
                   read_for_this_file=entry.get("read_for_this_file"), basis=entry.get("basis"),
                   per_file_basis=entry.get("per_file_basis"), prior_range=_pair(entry.get("prior_range")),
                   bob_error_normalized=entry.get("bob_error_normalized"),
                   defined_fraction=entry.get("defined_fraction"), entry=entry)

    def to_dict(self) -> dict:
        return self.entry

    @property
    def prior_only(self) -> bool:
        """Not read from the image: the answer is the prior's."""
        return self.read_from_image is False

    @property
    def read_mark(self) -> str:
        """The "read from the image?" cell: yes; no: prior only; no: not for this file (its interval spans most
        of the prior); unknown; "" where the answer carries no flag."""
        if "read_from_image" not in self.entry:
            return ""
        if self.read_from_image and self.read_for_this_file is False:
            return "no: not for this file"
        return "yes" if self.read_from_image else ("no: prior only" if self.read_from_image is False else "unknown")

    @property
    def basis_line(self) -> str | None:
        if self.basis is None:
            return None
        return f"{self.name}: {self.basis}" + (f"; {self.per_file_basis}" if self.per_file_basis else "")


@dataclass(frozen=True)
class Prediction:
    """The decoded Hamiltonian of one file: ``Ms`` (A/m, given or swept), ``parameters`` and ``combinations``
    (name → Estimate, in the answer's order), and ``notes`` (every other key of the answer: the estimator,
    the identification rules, the checks)."""

    Ms: float | None
    parameters: dict
    combinations: dict
    notes: dict

    @classmethod
    def from_dict(cls, result: dict) -> "Prediction":
        parameters, notes = {}, {}
        for name, entry in result.items():
            if name == "combinations":
                continue
            if isinstance(entry, dict) and "value" in entry:
                parameters[name] = Estimate.from_entry(name, entry)
            elif name != "Ms":
                notes[name] = entry
        combinations = {name: Estimate.from_entry(name, row, "combination")
                        for name, row in (result.get("combinations") or {}).items()}
        Ms = result.get("Ms")
        return cls(None if Ms is None else float(Ms), parameters, combinations, notes)

    def hamiltonian(self, defaults: dict | None = None) -> dict:
        """The simulator's parameter dict (SI): M_s and every parameter's value (N_pin rounded to a count)."""
        params = dict(defaults or {})
        if self.Ms is not None:
            params["Ms"] = self.Ms
        params.update({name: e.value for name, e in self.parameters.items()})
        if "N_pin" in params:
            params["N_pin"] = int(round(params["N_pin"]))
        return params

    @property
    def estimates(self) -> list:
        return [*self.parameters.values(), *self.combinations.values()]


def _number(value, width: int = 0, digits: int = 4) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return f"{'—':>{width}}"
    return f"{value:>{width}.{digits}g}"


def _interval(pair, markdown: bool) -> str:
    if pair is None:
        return "—" if markdown else f"{'—':>26}"
    if markdown:
        return f"{pair[0]:.3g}–{pair[1]:.3g}"
    return f"[{_number(pair[0], 11)}, {_number(pair[1], 11)}]"


def answer_table(prediction: Prediction, markdown: bool = False) -> list[str]:
    """The parameters, then the combinations, as a table (plain text for a terminal, Markdown for report.md):
    value, 68 and 90 % intervals, Bob's error (parameters) or the defined fraction (combinations), unit, and
    "read from the image?"; a prior-only quantity prints ``PRIOR_ONLY`` (a parameter with its prior range)."""
    lines = []
    groups = (("parameter", prediction.parameters, "Bob |err| (norm.)"),
              ("combination", prediction.combinations, "defined"))
    for title, estimates, extra in groups:
        if not estimates:
            continue
        if title == "combination":
            method = prediction.notes.get("combinations_method") or ("transforms of the joint posterior's draws "
                                                                      "(correlations between parameters kept)")
            lines += ["", f"derived combinations ({method}):"] if not markdown else ["", f"Derived combinations ({method}):", ""]
        if markdown:
            lines += [f"| {title} | value | 68 % interval | 90 % interval | {extra} | unit | read from the image? |",
                      "|---|---|---|---|---|---|---|"]
        else:
            lines.append(f"{title:<16}{'value':>12}  {'68 % interval':>26}  {'90 % interval':>26}  {extra:>18}  "
                         f"{'unit':<9}read from the image?")
        for e in estimates.values():
            other = e.bob_error_normalized if title == "parameter" else e.defined_fraction
            other_text = _number(other, 0 if markdown else 18, 3) if other is not None else ("—" if markdown else f"{'—':>18}")
            if e.prior_only:
                shown = PRIOR_ONLY + (f" (prior range {e.prior_range[0]:.4g} to {e.prior_range[1]:.4g})"
                                      if e.prior_range else "")
                if markdown:
                    lines.append(f"| {e.name} | {shown} | — | — | {other_text if title == 'combination' else '—'} | "
                                 f"{e.unit} | no |")
                else:
                    lines.append(f"{e.name:<16}{shown:<88}  {e.unit:<9}no")
                continue
            value = "undefined" if e.value is None else _number(e.value)
            if markdown:
                lines.append(f"| {e.name} | {value} | {_interval(e.interval_68, True)} | {_interval(e.interval_90, True)} | "
                             f"{other_text} | {e.unit} | {e.read_mark or '—'} |")
            else:
                lines.append(f"{e.name:<16}{value:>12}  {_interval(e.interval_68, False)}  "
                             f"{_interval(e.interval_90, False)}  {other_text}  {e.unit:<9}{e.read_mark}")
    return lines


def basis_lines(prediction: Prediction, markdown: bool = False) -> list[str]:
    """Why each quantity is (or is not) read from the image, and which ones this file identifies."""
    bases = [e.basis_line for e in prediction.estimates if e.basis_line]
    lines = []
    if bases:
        rule = prediction.notes.get("identification_rule")
        if markdown:
            lines += ["", f"Read from the image? {rule or ''}:", "", *(f"- {b}" for b in bases)]
        else:
            lines += ["", f"read from the image? ({rule})" if rule else "read from the image?", *(f"  {b}" for b in bases)]
    if "identified_for_this_file" in prediction.notes:
        named = ", ".join(prediction.notes["identified_for_this_file"]) or "nothing"
        text = f"this file identifies: {named} ({prediction.notes.get('per_file_rule', '')})"
        lines += ["", text[0].upper() + text[1:] + "."] if markdown else [text]
    return lines


__all__ = ["Estimate", "PRIOR_ONLY", "Prediction", "answer_table", "basis_lines"]
