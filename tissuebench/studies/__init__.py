"""Studies: runs, sweeps, timing protocol, the results store and the command line."""
