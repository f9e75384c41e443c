"""The FORC protocol (field sweeps of the simulated film) and the 64×64 rasterization."""

from .protocol import ForcFamily, SweepSettings, quasistatic_family

__all__ = ["ForcFamily", "SweepSettings", "quasistatic_family"]
