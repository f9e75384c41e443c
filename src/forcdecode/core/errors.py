"""Typed errors of the library. Library code raises these; only the command-line layer
(``forcdecode.cli.main``) turns a :class:`ForcdecodeError` into ``error: <message>`` and exit code 2."""

from __future__ import annotations


class ForcdecodeError(Exception):
    """Base of every error the library reports to a user (the CLI prints it and exits with 2)."""


class ConfigError(ForcdecodeError, ValueError):
    """A configuration that does not validate (the message names the key and the file)."""


class InputFileError(ForcdecodeError):  # measured.ForcFormatError is one
    """An input file that is missing, unreadable or malformed (the message names the path)."""


class DatasetError(ForcdecodeError):
    """A dataset that cannot serve the request (e.g. too few FORC families to train)."""


class ModelFileError(ForcdecodeError):
    """A trained-model file that is missing, unreadable or of another format."""


class OutOfDomainError(ForcdecodeError):
    """An input outside the training domain of the networks."""


class PriorClassError(OutOfDomainError):
    """A measured file whose loop contradicts the prior class the model was trained on (e.g. an in-plane
    loop given to a model of the ``perpendicular`` class); the message gives the reason and the measured
    numbers, ``check`` the whole check (``learn.prior_class.check_prior_class``)."""

    def __init__(self, message: str, check: dict | None = None):
        super().__init__(message)
        self.check = dict(check or {})


class SimulationError(ForcdecodeError, RuntimeError):
    """A micromagnetic simulation that diverged or did not converge (raised by the engine)."""


__all__ = ["ForcdecodeError", "ConfigError", "InputFileError", "DatasetError", "ModelFileError",
           "OutOfDomainError", "PriorClassError", "SimulationError"]
