"""Command-line interface: ``forcdecode <command> ...``.

Each command lives in the sub-package it belongs to and exposes ``add_arguments(parser)`` and
``run(args)``; this module only wires them together, importing lazily so that ``forcdecode --help``
stays fast. Exit codes live here: 0 success, 2 a library error (``ForcdecodeError``, printed as
``error: <message>``) or a usage error, 130 interrupted.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from ._runtime import limit_blas_threads, tune_allocator
from .core.errors import ForcdecodeError

# command name -> (module, one-line help)
COMMANDS = {
    "bench": ("forcdecode.bench.cli", "benchmarks that print figures (engine throughput, FORC family)"),
    "read": ("forcdecode.measured.cli", "read a measured FORC file and print a summary"),
    "diagram": ("forcdecode.forc.cli", "FORC diagram (Pike et al. local polynomial) of a measured or simulated family"),
    "loop": ("forcdecode.loop.cli", "close the loop on a measured file: domain check, re-simulation, residual effects"),
    "dataset": ("forcdecode.dataset.cli", "workflow stages: draw, screen, select, simulate, merge, figure1"),
    "learn": ("forcdecode.learn.cli", "workflow stages: train Alice and Bob for one parameter, evaluate and plot"),
    "closed-loop": ("forcdecode.loop.closed_loop_cli", "workflow stage: re-simulate the predicted Hamiltonians of the simulated test set"),
    "fit": ("forcdecode.infer.fit_cli", "refine the posterior of one FORC family by simulating that film (importance sampling)"),
    "fit-step": ("forcdecode.infer.fit_step_cli", "workflow stage: the refinement of `fit` one round per job (init, round, report)"),
    "posterior-loop": ("forcdecode.infer.posterior_loop_cli", "workflow stage: re-simulate posterior draws of the simulated test set against the floor"),
    "predict": ("forcdecode.learn.predict_cli", "predict the Hamiltonian (with uncertainties) from a FORC file or image and M_s"),
    "models": ("forcdecode.learn.models_cli", "the trained models shipped with the package: show, ship, check a fresh run against them"),
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="forcdecode", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (module_name, help_text) in COMMANDS.items():
        sub_parser = sub.add_parser(name, help=help_text)
        sub_parser.set_defaults(_module=module_name)
        # Arguments are added on demand (see main) to keep start-up fast.
    return parser


def main(argv: list[str] | None = None) -> int:
    tune_allocator()
    limit_blas_threads()
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    if argv and argv[0] in COMMANDS:
        module = importlib.import_module(COMMANDS[argv[0]][0])
        command_parser = argparse.ArgumentParser(prog=f"forcdecode {argv[0]}",
                                                 description=COMMANDS[argv[0]][1])
        module.add_arguments(command_parser)
        args = command_parser.parse_args(argv[1:])

        try:
            return int(module.run(args) or 0)
        except ForcdecodeError as error:
            print(f"error: {error}", file=sys.stderr)
            return 2
        except KeyboardInterrupt:
            print("interrupted", file=sys.stderr)
            return 130
    parser.parse_args(argv)  # prints help / error for unknown commands
    return 2


if __name__ == "__main__":
    sys.exit(main())
