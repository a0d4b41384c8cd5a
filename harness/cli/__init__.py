"""Entry points: the ``study`` and ``ftgspp`` commands, the Hydra training app, the tracking
server and the ``make reports`` planner. Every other wing is imported from here; nothing
imports this wing."""
