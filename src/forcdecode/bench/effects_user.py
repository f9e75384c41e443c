"""The loop as a user runs it, judged on the committed case sets (``forcdecode bench effects --independent``
without ``--oracle``; issue 59's laptop sets ``--set laptop-dev|laptop-eval``).

Per case: the magnum.np sample (``effects_independent.stored_sample``, kept in a store so that it is made
once), recorded by the case's instrument model into an instrument file (MicroMag 0015 or Lake Shore CSV);
then ``forcdecode loop FILE --out DIR --Ms-kA-m M`` through the loop's own parser and ``run``, M the truth
× the case's M_s error factor and nothing else of the truth. Each answer is scored beside the trivial
rules ``always_none`` and ``always_largest_gain`` on the same candidates (correct / partial / wrong /
none), with two-sided 90 % Clopper-Pearson intervals, detection against effect size, the issue's
targets, and the wall time a user waits. Rows are appended one per case (resumable; each records the
commit of the code that ran it).
"""

from __future__ import annotations

import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..core import physics as phys
from ..core.errors import ConfigError, ForcdecodeError, ModelFileError
from ..core.io import append_jsonl, read_json, write_json
from ..core.provenance import source_commit
from ..loop import command
from ..loop.command import resolve_estimator
from ..loop.effects import COMPONENTS, NO_EFFECT_MEMBERS
from ..reference.independent import (IndependentFilm, InstrumentModel, measurement_protocol, pins_for_density,
                                     write_measurement)
from .effects_independent import MS_ERROR, NO_EFFECT_VERDICTS, SAME_OBSERVABLE, _sig, draw_hamiltonians, stored_sample


USER_LOOP_ARGS = ()
"""The options of the README's first `forcdecode loop FILE` command (after FILE --out DIR): the command
the bench measures (a test checks the README still shows it). The bench adds ``--Ms-kA-m`` (the
truth × the case's M_s error factor) and nothing else. Since 2026-12-02 the loop's defaults (no
``--refit``): every verdict has its realisation floor on that path too, and it is the one a file can
be answered on in minutes (the refit path took 700-1006 s per dev control; its four dev rows stay in
the rows file under their own options, ``--loop-args "--refit K_u,A_ex,D"`` runs it)."""

BENCH_SETS = ("--out", "--Ms-kA-m", "--Ms-sweep-kA-m", "--params")
"""Loop options the bench sets itself (refused in ``--loop-args``)."""

FALLBACKS = ("population-median",)
"""What a user without a trained estimator can do (``--without-estimator``): ``population-median``
hands the loop (``--params``) the median film of the screened prior at the given M_s: K_u from the
median Q, A_ex from the median exchange length, D, σ_θ, σ_K their medians, N_pin 0 (the screened
draws of ``draw_hamiltonians`` from ids 900000.., none a case's)."""


class EstimatorUnavailableError(ModelFileError):
    """The trained estimator the loop needs is missing: the bench runs the loop as a user does and refuses."""


def _loop_module():
    """The `forcdecode loop` command as a user runs it (``loop.command``: its parser and its ``run``)."""

    return command


def loop_namespace(argv):
    """``argv`` parsed by the `forcdecode loop` parser itself (its defaults are the loop's)."""
    import argparse

    module = _loop_module()
    parser = argparse.ArgumentParser(prog="forcdecode loop", exit_on_error=False)
    module.add_arguments(parser)
    return parser.parse_args(list(argv))


def check_loop_args(loop_args) -> None:
    """ConfigError where ``loop_args`` set what the bench sets or do not parse."""
    import argparse


    taken = [a for a in loop_args if a.split("=")[0] in BENCH_SETS]
    if taken:
        raise ConfigError(f"--loop-args: {', '.join(taken)} is set by the bench (M_s from the case, its own --out)")
    try:
        loop_namespace(["FILE", "--out", "OUT", *loop_args])
    except (argparse.ArgumentError, SystemExit) as error:
        raise ConfigError(f"--loop-args {' '.join(loop_args)!r} do not parse as `forcdecode loop` options: {error}")


def check_estimator(loop_args, fallback: str | None = None) -> str:
    """The estimator the loop will use ("alice", "posterior" or "fallback: ..."); EstimatorUnavailableError
    (a ModelFileError) when the trained estimator the loop needs is missing and no ``fallback`` is asked for."""

    if fallback is not None:
        if fallback not in FALLBACKS:
            raise ConfigError(f"--without-estimator {fallback!r}: one of {', '.join(FALLBACKS)}")
        return f"fallback: {fallback}"
    args = loop_namespace(["FILE", "--out", "OUT", *loop_args])

    resolve_estimator(args)  # --estimator auto as the loop resolves it (and the posterior's default path)
    try:
        if args.estimator == "alice":
            # loads torch: imported only when this runs
            from ..learn.predictor import load_models

            load_models(args.models)
        else:
            if not Path(args.posterior).exists():
                raise ModelFileError(f"no posterior at {args.posterior}")
    except ModelFileError as error:
        raise EstimatorUnavailableError(
            f"the bench runs `forcdecode loop` as a user does, the Hamiltonian from the trained estimator "
            f"({args.estimator}), and none is there: {error}. Train it (the main job: make run / snakemake), or "
            f"measure what a user without one gets with --without-estimator {FALLBACKS[0]} (reported as such); "
            "the truth is never handed to the loop") from error
    return args.estimator


def population_median_hamiltonian(Ms: float, n: int = 400) -> dict:
    """``FALLBACKS``' population-median film at ``Ms`` (no case's truth enters)."""
    mu0 = phys.MU0
    draws = [h for _, h in draw_hamiltonians(900000, n)]
    Q = np.median([phys.quality_factor(h["K_u"], h["Ms"]) for h in draws])
    l_ex = np.median([phys.exchange_length(h["A_ex"], h["Ms"]) for h in draws])
    return {"Ms": float(Ms), "K_u": _sig(Q * mu0 * Ms**2 / 2), "A_ex": _sig(l_ex**2 * mu0 * Ms**2 / 2),
            **{k: _sig(np.median([h[k] for h in draws])) for k in ("D", "sigma_theta_deg", "sigma_K")}, "N_pin": 0}


def case_film(case: dict):
    """The magnum.np film of a case (``reference.independent.IndependentFilm``)."""


    s = case["sample"]
    film = IndependentFilm(nx=s["nx"], ny=s["ny"], cell_nm=s["cell_nm"], n_grains=s["n_grains"],
                           anisotropy_distribution=s["anisotropy_distribution"],
                           sweep_step_T=case["protocol"]["sweep_step_T"],
                           grain_sizes=s.get("grain_sizes", "equal"), pin_orientation=s.get("pin_orientation", "isotropic"))
    pins = pins_for_density(case["hamiltonian"].get("N_pin", 0), film)
    return film if not pins else replace(film, pinning_cells=pins)


def case_sample(case: dict, cache_dir=None, samples_dir=None) -> tuple:
    """(the magnum.np sample of ``case``: its film, Hamiltonian, physics, seed, protocol and patches;
    seconds spent on it, ~0 where ``samples_dir`` holds it already)."""

    film = case_film(case)
    protocol = measurement_protocol(case["protocol"]["curves"], 1.0, case["protocol"]["shift"])
    start = time.perf_counter()
    sample = stored_sample(samples_dir, dict(case["hamiltonian"]), dict(case["physics"]), case["realisation_seed"],
                           cache_dir, protocol, film, patches=int(case.get("patches", 1)))
    return sample, time.perf_counter() - start


def case_file(case: dict, work_dir, cache_dir=None, samples_dir=None) -> tuple[Path, float]:
    """(the instrument file of ``case``, seconds spent on its magnum.np sample)."""

    film = case_film(case)
    truth = dict(case["hamiltonian"])
    sample, sample_s = case_sample(case, cache_dir=cache_dir, samples_dir=samples_dir)
    suffix = {"micromag0015": "frc", "lakeshore_csv": "csv"}[case["format"]]
    path = write_measurement(Path(work_dir) / f"{case['name']}.{suffix}", sample, truth["Ms"] * film.moment_Am2,
                             InstrumentModel(noise=case["noise"], **case["instrument"]), seed=case["realisation_seed"],
                             fmt=case["format"])
    return path, sample_s


def given_Ms(case: dict) -> float:
    """The M_s (A/m) a user gives the loop for ``case``: the truth × the case's M_s error factor."""
    return case["hamiltonian"]["Ms"] * case["Ms_error_factor"]


def user_loop_argv(case: dict, path, out, loop_args=USER_LOOP_ARGS) -> list[str]:
    """`forcdecode loop` arguments (after ``loop``) of ``case``'s file as a user gives them:
    FILE --out OUT LOOP_ARGS --Ms-kA-m M (``given_Ms``), nothing else of the truth."""
    return [str(path), "--out", str(out), *loop_args, "--Ms-kA-m", f"{given_Ms(case) / 1e3:.6g}"]


def run_user_case(case: dict, work_dir, loop_args=USER_LOOP_ARGS, fallback: str | None = None, cache_dir=None,
                  samples_dir=None) -> dict:
    """One case as a user runs it: the magnum.np sample recorded in an instrument file, then
    `forcdecode loop FILE --out DIR LOOP_ARGS --Ms-kA-m M` through the loop's own parser and ``run``
    (M = the truth × the case's M_s error factor; with ``fallback`` ``--params`` of that film instead).
    Nothing else of the truth reaches the loop. Returns the JSON-ready row (``user_row``)."""


    work = Path(work_dir)
    try:
        path, sample_s = case_file(case, work / "files", cache_dir=cache_dir, samples_dir=samples_dir)
    except RuntimeError as error:  # magnum.np did not converge: no file, no case (counted apart, not scored)
        return {"case": case["name"], "split": case["split"], "kind": case["kind"], "class": case["class"],
                "status": "sample failed", "error": str(error), "loop_argv": [], "estimator": None,
                "oracle_inputs": False}
    out = work / "loop" / case["name"]
    if fallback is None:
        argv = user_loop_argv(case, path, out, loop_args)
    else:
        write_json(out / "fallback_params.json", population_median_hamiltonian(given_Ms(case)))
        argv = [str(path), "--out", str(out), *loop_args, "--params", str(out / "fallback_params.json")]
    start = time.perf_counter()
    module = _loop_module()
    try:
        module.run(loop_namespace(argv))
        report = read_json(out / "report.json", what="loop report")
    except ForcdecodeError as error:  # what the user would see as `error: ...`: an answer naming nothing
        report = {"status": f"error: {error}"}
    # the estimator that answered: the loop's resolution of --estimator auto where it made one
    used = (report.get("estimator_choice") or {}).get("estimator") or loop_namespace(argv).estimator
    return user_row(case, report, argv=argv, estimator=f"fallback: {fallback}" if fallback else used,
                    sample_s=sample_s, loop_s=time.perf_counter() - start)


HAMILTONIAN_CHANGE = "K_u change"
"""The member an ambiguous set gives the decoded Hamiltonian's own neighbourhood
(``loop.effects.HAMILTONIAN_CHANGE``): a change of the Hamiltonian, not an effect."""


def _answer_of_report(report: dict) -> dict:
    """What the loop answered: {"named": [effects], "ambiguous": bool, "refused": status or None}. An
    "ambiguous" verdict names the set it lists (analysis "ambiguous_set"/"ambiguous", or "ambiguous: a, b")."""
    if report.get("status") != "analysed":
        return {"named": [], "ambiguous": False, "refused": report.get("status")}
    verdict = report.get("verdict") or "none"
    if verdict in NO_EFFECT_VERDICTS:
        return {"named": [], "ambiguous": False, "refused": None}
    if verdict.startswith("ambiguous"):
        analysis = report.get("analysis") or {}
        names = analysis.get("ambiguous_set") or analysis.get("ambiguous")
        if not isinstance(names, (list, tuple)):
            names = [n.strip() for n in verdict.partition(":")[2].strip(" ()").split(",") if n.strip()]
        return {"named": sorted(n for n in names if n != HAMILTONIAN_CHANGE and n not in NO_EFFECT_MEMBERS),
                "ambiguous": True, "refused": None, "hedged": HAMILTONIAN_CHANGE in names,
                "no_effect_member": sorted(n for n in names if n in NO_EFFECT_MEMBERS)}
    return {"named": [report.get("effect") or verdict], "ambiguous": False, "refused": None}


def answer_set_size(answer: dict) -> int:
    """Members of an answer's set: the effects it names, plus the Hamiltonian's own change where the
    set held it (``hedged``)."""
    return len(answer["named"]) + int(bool(answer.get("hedged")))


def largest_gain_answer(candidates: dict) -> dict:
    """``always_largest_gain``: the candidate with the largest held-out relative gain, no gate ("none"
    when no candidate gains)."""
    gains = {k: v.get("relative_gain") for k, v in candidates.items() if k not in ("none", HAMILTONIAN_CHANGE)}
    gains = {k: g for k, g in gains.items() if g is not None and np.isfinite(g)}
    best = max(gains, key=gains.get) if gains else None
    return {"named": [best] if best is not None and gains[best] > 0 else [], "ambiguous": False, "refused": None}


def score_answer(kind: str, true_class: str, answer: dict) -> str:
    """"correct", "partial" or "wrong". Library case: correct when the one effect named is the true one
    (or one no FORC measurement tells from it, ``SAME_OBSERVABLE``); partial when an ambiguous answer's
    set holds it (never correct); else wrong. Control or outside case: correct when no effect is named
    (none, an unexplained structured residual, or a refusal), else wrong: an ambiguous set naming an
    effect is an attribution, also where it holds the Hamiltonian's own change ("hedged", counted
    apart by ``rule_metrics``), but not where it holds realisation noise or a switching-field
    distribution (``no_effect_member``: the loop says the residual may be no effect). ``named`` never
    holds ``HAMILTONIAN_CHANGE`` or those members."""
    named = answer["named"]
    if kind in ("control", "outside"):
        # an ambiguous set that holds realisation noise (or a switching-field distribution) says the
        # residual may be no effect: not an attribution (``loop.effects.NO_EFFECT_MEMBERS``)
        return "wrong" if named and not answer.get("no_effect_member") else "correct"

    def matches(name):
        return name == true_class or any({name, true_class} <= group for group in SAME_OBSERVABLE)

    if answer["ambiguous"]:
        return "partial" if any(matches(n) for n in named) else "wrong"
    return "correct" if len(named) == 1 and matches(named[0]) else "wrong"


RULES = ("loop", "always_none", "always_largest_gain")


def user_row(case: dict, report: dict, argv=(), estimator: str = "", sample_s: float = float("nan"),
             loop_s: float = float("nan")) -> dict:
    """The row of one case: the case, what the loop answered, its candidates' held-out records,
    the answers (and scores, held-out reductions) of the loop and of the two trivial rules, and the
    commit of the code that ran it (``core.provenance.source_commit``)."""
    analysis = report.get("analysis") or {}
    candidates = {k: {key: v.get(key) for key in ("heldout_rms", "relative_gain", "accepted", "kind", "null_gain",
                                                   "beats_null")}
                  for k, v in (analysis.get("candidates") or {}).items()}
    before = report.get("heldout_rms_before")
    answers = {"loop": _answer_of_report(report),
               "always_none": {"named": [], "ambiguous": False, "refused": None},
               "always_largest_gain": largest_gain_answer(candidates)}
    reductions = {}
    for rule, answer in answers.items():
        if len(answer["named"]) != 1 or answer["ambiguous"] or not before:
            reductions[rule] = None
        elif rule == "loop":
            reductions[rule] = 1 - report["heldout_rms_after"] / before
        else:
            rms = candidates.get(answer["named"][0], {}).get("heldout_rms")
            reductions[rule] = None if rms is None else 1 - rms / before
    return {"case": case["name"], "split": case["split"], "kind": case["kind"], "class": case["class"],
            "size": case.get("size"), "in_prior": case.get("in_prior", True), "oracle_inputs": False,
            "estimator": estimator, "loop_argv": [str(a) for a in argv], "status": report.get("status"),
            "verdict": report.get("verdict"), "chosen": report.get("effect"),
            "heldout_rms_before": before, "heldout_rms_after": report.get("heldout_rms_after"),
            "Ms_given_A_per_m": (report.get("parameters") or {}).get("Ms"),
            "parameters": report.get("parameters"), "truth": case["hamiltonian"],
            "null_realisations": ((report.get("patches") or {}).get("null_films")
                                  or (loop_namespace(argv).null_realisations if argv else None)),
            "candidates": candidates, "answers": answers,
            "scores": {rule: score_answer(case["kind"], case["class"], a) for rule, a in answers.items()},
            "heldout_reduction": reductions, "sample_s": sample_s, "loop_s": loop_s,
            "patches": int(case.get("patches", 1)), "pinned": bool(case["hamiltonian"].get("N_pin", 0)),
            "variant": (case.get("sample") or {}).get("variant", "standard"),
            "patch_estimate": (report.get("patches") or {}).get("estimate"),
            "null_gain_per_film": (report.get("patches") or {}).get("null_gain_per_film"),
            "code_commit": source_commit()}


def clopper_pearson(k: int, n: int, level: float = 0.9):
    """Two-sided Clopper–Pearson (exact binomial) interval of k successes in n at ``level``; None for n = 0."""
    from scipy.stats import beta

    if n == 0:
        return None
    a = (1 - level) / 2
    lo = 0.0 if k == 0 else float(beta.ppf(a, k, n - k + 1))
    hi = 1.0 if k == n else float(beta.ppf(1 - a, k + 1, n - k))
    return [lo, hi]


def _rate(rows, test):
    k = sum(bool(test(r)) for r in rows)
    n = len(rows)
    return (k / n if n else None), clopper_pearson(k, n), k


def rule_metrics(rows: list[dict], rule: str) -> dict:
    """The issue's keys for one rule (``RULES``) over ``rows`` (``user_row``)."""
    library = [r for r in rows if r["kind"] == "library"]
    controls = [r for r in rows if r["kind"] == "control"]
    outside = [r for r in rows if r["kind"] == "outside"]
    out = {}
    for key, group, test in (("correct_fraction", library, lambda r: r["scores"][rule] == "correct"),
                             ("partial_fraction", library, lambda r: r["scores"][rule] == "partial"),
                             ("false_attribution_controls", controls, lambda r: r["scores"][rule] == "wrong"),
                             ("false_attribution_outside_library", outside, lambda r: r["scores"][rule] == "wrong")):
        out[key], out[f"{key}_ci90"], out[f"{key}_k"] = _rate(group, test)
    for key, group in (("hedged_controls_k", controls), ("hedged_outside_library_k", outside)):
        # false attributions that were ambiguous sets holding the Hamiltonian's change beside the effect
        out[key] = sum(r["scores"][rule] == "wrong" and bool(r["answers"][rule].get("hedged")) for r in group)
    # a partial answer's size: how many members the set holds (the Hamiltonian's change counted), so a
    # set of two that holds the truth is told from one of five
    sizes = [answer_set_size(r["answers"][rule]) for r in library if r["scores"][rule] == "partial"]
    out["partial_set_sizes"] = sorted(sizes)
    out["partial_set_size_median"] = float(np.median(sizes)) if sizes else None
    reductions = [r["heldout_reduction"][rule] for r in rows if r["heldout_reduction"][rule] is not None]
    out["median_heldout_reduction"] = float(np.median(reductions)) if reductions else None
    out["n_named"] = len(reductions)
    return out


TARGETS = {"correct_fraction": (">=", 0.9), "false_attribution_controls": ("<=", 0.1),
           "false_attribution_outside_library": ("<=", 0.1), "median_heldout_reduction": (">=", 0.5)}
"""The issue's targets (docs/results/effects.md: ≥ 0.9, ≤ 0.1 (was 0), ≤ 0.1, held-out after/before ≤ 0.5)."""


def meets(metrics: dict, target: str) -> bool:
    """Met by its 90 % interval (a rate: the lower bound ≥ / upper bound ≤ the target; the median: its value)."""
    side, value = TARGETS[target]
    ci = metrics.get(f"{target}_ci90")
    point = metrics.get(target)
    if point is None:
        return False
    x = (ci[0] if side == ">=" else ci[1]) if ci is not None else point
    return x >= value if side == ">=" else x <= value


def beats(loop: dict, other: dict, target: str) -> bool:
    """The loop better than ``other`` on ``target`` beyond both 90 % intervals (the median: its value;
    a rule that names nothing has none, and is beaten by any median)."""
    side, _ = TARGETS[target]
    a, b = loop.get(target), other.get(target)
    if a is None:
        return False
    if b is None:
        return True
    ca, cb = loop.get(f"{target}_ci90"), other.get(f"{target}_ci90")
    if ca is None or cb is None:
        return a > b if side == ">=" else a < b
    return ca[0] > cb[1] if side == ">=" else ca[1] < cb[0]


def target_verdicts(loop: dict, trivial: dict) -> dict:
    """Per target: met by the loop's interval, met by each trivial rule, the loop beats each; and
    ``counts``: the loop meets it and, for each trivial rule, beats it there, or (where the rule meets
    it by doing nothing) beats it on a target the rule fails: a target met by answering "none" counts
    only beside a loop that also does what "none" cannot."""
    out = {}
    for t in TARGETS:
        row = {"target": list(TARGETS[t]), "loop_meets": meets(loop, t)}
        ok = row["loop_meets"]
        for rule, m in trivial.items():
            row[f"{rule}_meets"] = meets(m, t)
            row[f"beats_{rule}"] = beats(loop, m, t)
            elsewhere = any(beats(loop, m, u) for u in TARGETS if u != t and not meets(m, u))
            ok = ok and (row[f"beats_{rule}"] or (row[f"{rule}_meets"] and elsewhere))
        row["counts"] = bool(ok)
        out[t] = row
    return out


def _isotonic(y: np.ndarray) -> np.ndarray:
    """Pool-adjacent-violators: the non-decreasing fit of ``y`` (equal weights)."""
    blocks = [[float(v), 1] for v in y]
    merged = []
    for b in blocks:
        merged.append(b)
        while len(merged) > 1 and merged[-2][0] / merged[-2][1] > merged[-1][0] / merged[-1][1]:
            s, n = merged.pop()
            merged[-1][0] += s
            merged[-1][1] += n
    return np.concatenate([np.full(n, s / n) for s, n in merged])


def detection_by_size(rows: list[dict], rule: str = "loop", bins: int = 3) -> dict:
    """Per in-library class, over its in-prior cases: the points (size, named), the rate in ``bins``
    equal-count size bins with Clopper–Pearson 90 % intervals, and ``size_50``: the smallest size
    named half the time, read off the isotonic (non-decreasing) fit of named-or-not against size,
    interpolated linearly between the sizes where it crosses 0.5 (None when it never reaches 0.5;
    the smallest size when it is ≥ 0.5 there); beside it the median realisation floor the true
    candidate met (relative gain of effect-free films) and the loop's ``--null-realisations``: whether
    the floor was estimated on enough realisations for the sizes read."""
    out = {}
    for name in sorted({r["class"] for r in rows if r["kind"] == "library"}):
        points = sorted((float(r["size"]), r["scores"][rule] == "correct") for r in rows
                        if r["class"] == name and r.get("in_prior", True) and r.get("size") is not None)
        if not points:
            continue
        x = np.array([p[0] for p in points])
        y = np.array([p[1] for p in points], float)
        fit = _isotonic(y)
        size_50 = None
        above = np.flatnonzero(fit >= 0.5)
        if above.size:
            j = int(above[0])
            if j == 0:
                size_50 = float(x[0])
            else:
                f0, f1 = fit[j - 1], fit[j]
                size_50 = float(x[j - 1] + (0.5 - f0) / (f1 - f0) * (x[j] - x[j - 1]))
        table = []
        for part in np.array_split(np.arange(len(points)), min(bins, len(points))):
            k, n = int(y[part].sum()), len(part)
            table.append({"size_range": [float(x[part[0]]), float(x[part[-1]])], "named": k, "n": n,
                          "rate": k / n, "rate_ci90": clopper_pearson(k, n)})
        floors = [((r.get("candidates") or {}).get(name) or {}).get("null_gain") for r in rows if r["class"] == name]
        floors = [f["relative"] for f in floors if isinstance(f, dict) and f.get("relative") is not None]
        out[name] = {"points": [[float(a), bool(b)] for a, b in points], "bins": table, "size_50": size_50,
                     # the realisation floor the true candidate was judged against (loop --null-realisations)
                     "floor_relative_gain_median": float(np.median(floors)) if floors else None,
                     "null_realisations": sorted({r.get("null_realisations") for r in rows if r["class"] == name
                                                  and r.get("null_realisations") is not None})}
    return out


INTERVALS = "Clopper-Pearson (exact binomial), two-sided 90 %"


INSTRUMENT_COMPONENTS = frozenset(COMPONENTS)
"""The measurement-side effects (``loop.effects.COMPONENTS``); an answer made only of them (singles or
"a+b" combinations) names the instrument, anything else (K_2, a bias field, a tilt, a second phase,
thermal activation) a physics term."""


def names_physics(answer: dict) -> bool:
    """Whether ``answer`` (``_answer_of_report``) names a physics term: an effect not made of
    ``INSTRUMENT_COMPONENTS`` alone."""
    return any(not set(name.split("+")) <= INSTRUMENT_COMPONENTS for name in answer["named"])


OUTCOMES = ("correct", "partial", "wrong", "none", "refused")


def outcome(row: dict, rule: str = "loop") -> str:
    """A row's outcome in the issue's terms: ``correct``, ``partial`` (the true effect inside an
    ambiguous set), ``wrong`` (an effect named and not the true one; on a control or outside case,
    any effect named), ``none`` (nothing named: none, an unexplained residual, an ambiguous set of
    no-effect members only) or ``refused`` (the loop answered no analysis, e.g. out of the training
    distribution)."""
    answer = row["answers"][rule]
    if answer.get("refused") is not None:
        return "refused"
    score = row["scores"][rule]
    if score in ("correct", "partial") and row["kind"] == "library":
        return score
    return "wrong" if answer["named"] and score == "wrong" else "none"


def outcomes_by_class(rows: list[dict], rule: str = "loop") -> dict:
    """Per class (controls under "none"): {outcome: count} over ``OUTCOMES``, and ``n``."""
    out = {}
    for r in rows:
        row = out.setdefault(r["class"], {**{o: 0 for o in OUTCOMES}, "n": 0})
        row[outcome(r, rule)] += 1
        row["n"] += 1
    return dict(sorted(out.items()))


LOOP_SECONDS_TARGET = 180.0
"""Issue 59: `forcdecode loop` ≤ 3 min per file on one core (judged on the median; the share of files
within it is printed beside)."""


def laptop_targets(result: dict, rows: list[dict]) -> dict:
    """Issue 59's targets on a laptop set, each {"target": text, "value": what was measured, "met": bool}:
    controls misattributed ≤ 0.05 with the 90 % upper bound ≤ 0.15; background detected ≥ 0.8 at the
    top of its size range (the top third of the pinned background cases by χ; the set's χ reaches
    0.08 /T, ≈ 10 % of M_sat at the laptop film's 1.2 T) with no physics term named on any pinned
    background case; in-library correct ≥ 0.8 with its 90 % interval above both trivial rules'; outside
    forced ≤ 0.1; held-out after/before ≤ 0.5 where an effect is named (median reduction ≥ 0.5); the
    loop's median wall time ≤ ``LOOP_SECONDS_TARGET``."""
    out = {}
    rate, ci = result.get("false_attribution_controls"), result.get("false_attribution_controls_ci90")
    out["controls"] = {"target": "false attributions <= 0.05, 90 % upper bound <= 0.15",
                       "value": [rate, ci], "met": rate is not None and rate <= 0.05 and ci[1] <= 0.15}
    background = sorted((float(r["size"]), r) for r in rows if r["class"] == "background" and r.get("pinned")
                        and r.get("size") is not None)
    top = [r for _, r in background[len(background) - max(1, len(background) // 3):]] if background else []
    k = sum(r["scores"]["loop"] == "correct" for r in top)
    physics = [r["case"] for _, r in background if names_physics(r["answers"]["loop"])]
    out["background_at_10_percent"] = {
        "target": "pinned background detected >= 0.8 in its top size third, no physics term named instead",
        "value": {"named": k, "n": len(top), "chi_per_T": [float(top[0]["size"]), float(top[-1]["size"])] if top else None,
                  "physics_named_on": physics},
        "met": bool(top) and k / len(top) >= 0.8 and not physics}
    rate, ci = result.get("correct_fraction"), result.get("correct_fraction_ci90")
    uppers = [m["correct_fraction_ci90"][1] for m in result["trivial"].values() if m.get("correct_fraction_ci90")]
    out["in_library"] = {"target": "correct >= 0.8, 90 % interval above both trivial rules'",
                         "value": [rate, ci], "met": rate is not None and rate >= 0.8 and all(ci[0] > u for u in uppers)}
    rate = result.get("false_attribution_outside_library")
    out["outside"] = {"target": "outside the library forced <= 0.1", "value": rate,
                      "met": rate is not None and rate <= 0.1}
    reduction = result.get("median_heldout_reduction")
    out["heldout"] = {"target": "held-out after/before <= 0.5 where an effect is named (median reduction >= 0.5)",
                      "value": reduction, "met": reduction is not None and reduction >= 0.5}
    seconds = [r["loop_s"] for r in rows if np.isfinite(r.get("loop_s", np.nan))]
    median = float(np.median(seconds)) if seconds else None
    out["loop_wait"] = {"target": f"forcdecode loop <= {LOOP_SECONDS_TARGET:.0f} s per file on one core (median)",
                        "value": {"median_s": median, "within_share": (float(np.mean(np.array(seconds) <= LOOP_SECONDS_TARGET))
                                                                       if seconds else None)},
                        "met": median is not None and median <= LOOP_SECONDS_TARGET}
    return out


def summarize_user(rows: list[dict], wall_s: float = float("nan"), n_planned: int | None = None) -> dict:
    """The issue's summary of the user-path rows: the loop's keys at the top level, the trivial rules'
    under ``trivial``, the target verdicts, detection against size per class, and the rows (``cases``).
    ``n_planned``: the cases of the set; ``complete`` says whether every one has its row (a partial
    set's rates are those of the cases run so far, in the case file's order, not of the set)."""
    failed = [r for r in rows if r.get("status") == "sample failed"]
    rows = [r for r in rows if r.get("status") != "sample failed"]
    loop = rule_metrics(rows, "loop")
    trivial = {rule: rule_metrics(rows, rule) for rule in ("always_none", "always_largest_gain")}
    costs = [r["sample_s"] + r["loop_s"] for r in rows if np.isfinite(r.get("sample_s", np.nan) + r.get("loop_s", np.nan))]
    result = {"n_cases": len(rows), "n_controls": sum(r["kind"] == "control" for r in rows),
            "n_library": sum(r["kind"] == "library" for r in rows),
            "n_outside": sum(r["kind"] == "outside" for r in rows),
            "oracle_inputs": any(r.get("oracle_inputs", True) for r in rows) if rows else False,
            "Ms_error_max": MS_ERROR, "noise": "estimated by the loop from the file",
            "splits": sorted({r["split"] for r in rows}), "estimators": sorted({r["estimator"] for r in rows}),
            "loop_options": sorted({" ".join(_argv_options(r["loop_argv"])) for r in rows}),
            "code_commits": sorted({r.get("code_commit", "unrecorded") for r in rows}),
            "n_refused": sum(r["answers"]["loop"]["refused"] is not None for r in rows),
            "samples_failed": [{"case": r["case"], "error": r["error"]} for r in failed],
            **loop, "trivial": trivial, "targets": target_verdicts(loop, trivial), "intervals": INTERVALS,
            "detection": detection_by_size(rows), "median_case_s": float(np.median(costs)) if costs else None,
            "n_pinned": sum(bool(r.get("pinned")) for r in rows),
            "patches": sorted({int(r.get("patches", 1)) for r in rows}),
            "loop_seconds_median": (float(np.median([r["loop_s"] for r in rows if np.isfinite(r.get("loop_s", np.nan))]))
                                    if rows else None),
            "n_planned": n_planned, "complete": n_planned is None or len(rows) + len(failed) >= n_planned,
            "outcomes": {rule: outcomes_by_class(rows, rule) for rule in RULES},
            "wall_s": wall_s, "cases": rows + failed}
    if result["splits"] and all(split.startswith("laptop-") for split in result["splits"]):
        result["laptop_targets"] = laptop_targets(result, rows)  # issue 59's, on its laptop sets
    return result


def make_samples(cases: list[dict], samples_dir, cache_dir=None, out_jsonl=None, progress=None) -> dict:
    """The magnum.np samples of ``cases`` into ``samples_dir`` (``stored_sample``; one already there is not
    made again, so a killed run resumes), without running the loop: the expensive, loop-independent half
    of the bench, paid once and kept (a committed store survives the machine). Each case's line
    {case, sample_s, status, [error]} is appended to ``out_jsonl``. Returns {n_cases, made, stored,
    failed, sample_s_total, sample_s_median}."""
    lines = []
    for case in cases:
        try:
            sample, seconds = case_sample(case, cache_dir=cache_dir, samples_dir=samples_dir)
            line = {"case": case["name"], "sample_s": round(seconds, 1),
                    "status": "stored" if "stored" in sample.stats else "made"}
        except RuntimeError as error:  # magnum.np did not converge: recorded, the other cases go on
            line = {"case": case["name"], "sample_s": float("nan"), "status": "failed", "error": str(error)}
        lines.append(line)
        if out_jsonl is not None:
            append_jsonl(out_jsonl, line)
        if progress is not None:
            progress(line)
    made = [line["sample_s"] for line in lines if line["status"] == "made"]
    return {"n_cases": len(lines), "made": len(made),
            "stored": sum(line["status"] == "stored" for line in lines),
            "failed": [line["case"] for line in lines if line["status"] == "failed"],
            "sample_s_total": round(float(np.sum(made)), 1) if made else 0.0,
            "sample_s_median": round(float(np.median(made)), 1) if made else None}


def user_confusion(cases: list[dict], work_dir, loop_args=USER_LOOP_ARGS, fallback: str | None = None,
                   cache_dir=None, out_jsonl=None, progress=None, samples_dir=None, run: bool = True) -> dict:
    """Run ``cases`` on the user path (``run_user_case``); each finished row is appended to
    ``out_jsonl`` and a row already there with the same case, loop options and estimator is not run
    again (a killed run resumes). The magnum.np samples are kept in ``samples_dir`` (default
    ``work_dir``/samples). With ``run`` False no case is run: the summary of the rows already there (a
    run in progress, read without stopping it). Returns ``summarize_user`` over ``len(cases)`` planned."""
    work = Path(work_dir)
    finished = []
    estimator = check_estimator(loop_args, fallback)
    if out_jsonl is not None and Path(out_jsonl).exists():
        earlier = [json.loads(line) for line in Path(out_jsonl).read_text().splitlines() if line.strip()]
        finished = [r for r in earlier if _argv_options(r.get("loop_argv", [])) == list(loop_args)
                    and r.get("estimator") == estimator]
    seen = {r["case"] for r in finished}
    wanted = {c["name"] for c in cases}
    finished = [r for r in finished if r["case"] in wanted]
    start = time.perf_counter()
    for case in cases if run else ():
        if case["name"] in seen:
            continue
        row = run_user_case(case, work, loop_args=loop_args, fallback=fallback, cache_dir=cache_dir,
                            samples_dir=work / "samples" if samples_dir is None else samples_dir)
        finished.append(row)
        if out_jsonl is not None:
            append_jsonl(out_jsonl, row)
        if progress is not None:
            progress(row)
    return summarize_user(finished, wall_s=time.perf_counter() - start, n_planned=len(cases))


def _argv_options(argv) -> list[str]:
    """The loop options of a row's argv, without FILE, --out DIR and what the bench sets per case."""
    argv = list(argv)[1:]
    out, skip = [], 0
    for a in argv:
        if skip:
            skip -= 1
            continue
        if a in ("--out", "--Ms-kA-m", "--params"):
            skip = 1
            continue
        out.append(a)
    return out


def _short(value) -> str:
    """A measured value for one line: floats to 2-3 significant figures, lists and dicts likewise."""
    if isinstance(value, float):
        return f"{value:.3g}"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_short(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k}: {_short(v)}" for k, v in value.items()) + "}"
    return str(value)


def user_summary_lines(result: dict) -> list[str]:
    def rate(m, key):
        v, ci = m.get(key), m.get(f"{key}_ci90")
        return "—" if v is None else f"{v:.2f} [{ci[0]:.2f}, {ci[1]:.2f}] ({m[f'{key}_k']})"

    lines = [f"the loop as a user runs it ({', '.join(result['estimators'])}; options {result['loop_options']}), "
             f"{result['n_cases']} cases: {result['n_controls']} controls, {result['n_library']} in-library, "
             f"{result['n_outside']} outside; oracle inputs: {result['oracle_inputs']}; intervals {result['intervals']}",
             *([] if result.get("complete", True) else
               [f"PARTIAL: {result['n_cases'] + len(result['samples_failed'])} of {result['n_planned']} cases run so far "
                "(in the case file's order); the rates below are of these rows, not of the set"]),
             f"code: {', '.join(result.get('code_commits', ['unrecorded']))}"
             + (" (rows of more than one version of the code)" if len(result.get("code_commits", ())) > 1 else ""),
             "", "rule".ljust(22) + "correct".ljust(26) + "partial".ljust(26) + "false (controls)".ljust(26)
             + "false (outside)".ljust(26) + "median reduction"]
    for rule, m in (("loop", result), *result["trivial"].items()):
        red = m.get("median_heldout_reduction")
        lines.append(rule.ljust(22) + rate(m, "correct_fraction").ljust(26) + rate(m, "partial_fraction").ljust(26)
                     + rate(m, "false_attribution_controls").ljust(26)
                     + rate(m, "false_attribution_outside_library").ljust(26) + ("—" if red is None else f"{red:.2f}"))
    lines += ["", "targets (counted: the loop meets it by its interval and beats both trivial rules): "
              + ", ".join(f"{t} {'yes' if v['counts'] else 'no'}" for t, v in result["targets"].items())]
    for name, target in (result.get("laptop_targets") or {}).items():
        lines.append(f"  issue 59, {name}: {'met' if target['met'] else 'NOT met'} ({target['target']}; "
                     f"measured {_short(target['value'])})")
    lines += ["", "class".ljust(34) + "".join(o.ljust(9) for o in OUTCOMES) + "n"]
    for name, counts in (result.get("outcomes") or {}).get("loop", {}).items():
        lines.append(name[:33].ljust(34) + "".join(str(counts[o]).ljust(9) for o in OUTCOMES) + str(counts["n"]))
    lines.append("")
    for name, d in result["detection"].items():
        lines.append(f"{name}: named half the time from size {d['size_50']}; "
                     + "; ".join(f"{b['size_range'][0]:.3g}–{b['size_range'][1]:.3g}: {b['named']}/{b['n']}"
                                 for b in d["bins"]))
    lines += ["", "case".ljust(34) + "class".ljust(32) + "verdict".ljust(34) + "score   largest gain"]
    for r in result["cases"]:
        if r.get("status") == "sample failed":
            lines.append(r["case"][:33].ljust(34) + r["class"][:31].ljust(32) + "(magnum.np sample failed: not scored)")
            continue
        lines.append(r["case"][:33].ljust(34) + r["class"][:31].ljust(32) + str(r["verdict"])[:33].ljust(34)
                     + r["scores"]["loop"].ljust(8) + ",".join(r["answers"]["always_largest_gain"]["named"] or ["none"]))
    return lines
