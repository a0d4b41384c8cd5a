"""The reproducibility harness: Hydra configuration, MLflow tracking, studies and reports.

It wraps the ``ftgspp`` library (one-way import: harness -> ftgspp).
"""
