"""The closed loop: the residual of a re-simulated Hamiltonian against the input family, traced to the
effect the model lacks. The re-simulation itself is per-file inference (``infer.resimulate``; its two
entry points re-exported here)."""

from ..infer.resimulate import observation_error, resimulate

__all__ = ["observation_error", "resimulate"]
