"""Bottom layer of forcdecode: typed errors, file I/O helpers, the registry of named random streams
and the parameter table. It imports nothing else of the package; every other layer may import it."""
