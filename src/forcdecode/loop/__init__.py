"""The closed loop: re-simulate a predicted Hamiltonian and compare it with the input family."""

from ..infer.resimulate import observation_error, resimulate

__all__ = ["observation_error", "resimulate"]
