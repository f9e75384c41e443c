"""forcdecode: read the micromagnetic Hamiltonian of a perpendicular film out of its FORCs.

Sub-packages show the architecture:

- ``micromag``  the zero-temperature micromagnetic engine (numba LLG and minimizer)
- ``forc``      the FORC protocol (field sweeps, reversal curves) and rasterization
- ``measured``  readers for instrument files, drift and unit handling
- ``bench``     benchmarks (scripts that print figures)
"""

__version__ = "0.1.0"
