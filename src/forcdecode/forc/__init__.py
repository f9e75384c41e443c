"""The FORC protocol (field sweeps of the simulated film) and the 64×64 rasterization."""

from .protocol import ForcFamily, quasistatic_family

__all__ = ["ForcFamily", "quasistatic_family"]
