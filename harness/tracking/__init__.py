"""MLflow: the store (an explicit client with SQLite locking), the trainer's tracker, MLflow's
own run conventions, provenance, and reading runs back as records. Imports nothing else of
the harness."""
