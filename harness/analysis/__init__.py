"""Numbers from runs: per-cell aggregation, the claims' tests and verdicts, stability
ladders, speed against accuracy and the sources of run-to-run spread. Pure functions of a
per-run DataFrame; imports ``spec`` only."""
