"""What is asked: study files, the metric registry, Hydra composition of each run's config,
config hashes and the ``study run`` invocation. Imports nothing else of the harness."""
