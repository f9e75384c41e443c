"""``forcdecode loop FILE --out DIR``: the command-line entry of the loop (``loop.command``: its options,
their defaults and what it prints; the bench runs the same command through that module)."""

from .command import add_arguments, run

__all__ = ["add_arguments", "run"]
