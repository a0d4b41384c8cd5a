"""Diagnostics behind the paper's secrets, run on a trained model (``ftgspp diagnose``).

- ``diagnose``: ``run_diagnostics`` (what a training run calls) and the ``ftgspp diagnose`` command;
- ``lifetimes``: effective lifetimes and how they split static from moving content;
- ``motion``: velocity maps, x–t slices, motion error and flicker against ground truth;
- ``truth``: a scene's true Gaussians (``gt/gaussians.npz``) as a model, scored like a trained one;
- ``figures``: one matplotlib figure per PNG; ``flow_colors``: the flow colour wheel.

The package imports nothing itself: each module is imported where it is used.
"""
