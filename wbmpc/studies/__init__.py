"""Studies and command lines: the demo, benchmarks, Table I, experiments, sweeps."""
