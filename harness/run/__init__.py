"""Running a study: the runner, its per-run task, launchers, leases, progress and the
synthetic scenes a study generates. Imports ``spec`` and ``tracking``."""
