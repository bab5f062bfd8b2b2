"""CARLA closed loop: the leaderboard 2.0 agent (:mod:`.agent`) and LEAD's route logic and controllers.

Nothing in the package imports this: it depends on data transforms, models and training checkpoints, never the
other way round. Importing it needs neither CARLA nor the leaderboard.
"""
