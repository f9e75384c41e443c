"""``forcdecode bench information``: the dispatch of the target (bench/cli.py only forwards here)."""

from __future__ import annotations

import json
from pathlib import Path
from ..config import load_config, shipped_config
from ..core.errors import ConfigError
from ..core.io import write_json
from . import information_films as info

FILMS_TARGET_DEFAULT = ["laptop:20x2", "laptop_paper_grains:20x2", "box128:20x1", "box128:8x2", "paper:5x1"]
"""``--films``'s default belongs to ``bench films``; left at it, ``bench information`` runs the laptop film."""


def _stop_time(text, now=None):
    """The UTC time stamp (s) of the next HH:MM after ``now``: a stop at 01:25 asked at 23:40 is the
    next day's 01:25, not a time already past. None where no stop is asked."""
    if not text:
        return None
    import datetime as dt


    try:
        hh, mm = (int(v) for v in text.split(":"))
        now = now or dt.datetime.now(dt.timezone.utc)
        stop = now.replace(hour=hh, minute=mm, second=0, microsecond=0)
    except ValueError as error:
        raise ConfigError(f"--stop-at {text!r}: expected a UTC time HH:MM ({error})") from None
    if stop <= now:
        stop += dt.timedelta(days=1)
    return stop.timestamp()


def bench_information(args, say) -> int:
    out = Path(args.info_dir)
    plan = []
    for item in (["laptop"] if args.films == FILMS_TARGET_DEFAULT else args.films):
        name, _, counts = item.partition(":")
        n, R = args.fiducials, args.realisations
        if counts:
            try:
                n, R = (int(v) for v in counts.split("x"))
            except ValueError:
                raise ConfigError(f"--films {item!r}: expected FILM or FILM:NxR") from None
        if name not in info.FILMS:
            raise ConfigError(f"--films {item!r}: unknown film {name!r}; known: {', '.join(info.FILMS)}")
        if name in info.NOT_MEASURED:
            raise ConfigError(f"--films {name}: {info.NOT_MEASURED[name]}")
        plan.append((name, n, R))
    if not args.summarize_only:
        if args.workers < 1:
            raise ConfigError(f"--workers must be >= 1 (simulation processes at once; got {args.workers})")
        cfg = load_config(args.config or shipped_config("config"))
        fid_file = out / "fiducials.json"
        n_max = max(n for _, n, _ in plan)
        if fid_file.exists():
            fiducials = json.loads(fid_file.read_text())
            if len(fiducials["fiducials"]) < n_max:
                raise ConfigError(f"{fid_file} holds {len(fiducials['fiducials'])} fiducials, fewer than {n_max}: "
                                  "remove it (and the results made from it) to choose again")
        else:
            say(f"screening draws 0..{args.pool - 1} of seed {cfg['seed']} (the laptop film) for the regimes' mass")
            pool = info.screened_pool(cfg, args.pool, say=say)
            fiducials = info.choose_fiducials(pool, n_max)
            fiducials.update(seed=cfg["seed"], deltas=list(args.delta), realisations=args.realisations,
                             stability_fiducials=args.stability_fiducials,
                             pool_rows=[{k: p[k] for k in ("sample_id", "regime", "N_pin", "K_eff", "sigma_w")}
                                        for p in pool])
            write_json(fid_file, fiducials)
            say(f"wrote {fid_file}: mass {fiducials['screened_mass']}, allotted {fiducials['allotted']}")
        for film, n, R in plan:
            design = info.FiducialDesign(R, args.delta, args.stability_fiducials)
            info.run_fiducials(cfg, film, info.film_fiducials(film, fiducials["fiducials"])[:n], design, out,
                               say=say, stop_at=_stop_time(args.stop_at), workers=args.workers)
    if args.summarize_only:
        info.reanalyse(out, say=say)
    summary = info.summarize(out)
    write_json(out / "summary.json", summary)
    if summary["films"]:
        info.figure(summary, out / "information.png")
    for line in info.summary_lines(summary):
        say(line)
    if args.json:
        print(json.dumps({k: v for k, v in summary.items() if k != "fiducials"}))
    return 0
