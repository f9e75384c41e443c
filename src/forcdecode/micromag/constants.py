"""Physical constants (SI), in mumax3's conventions."""

from ..core.physics import GAMMA_LL, MU0

__all__ = ["GAMMA_LL", "MU0"]
