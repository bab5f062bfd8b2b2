"""Leaderboard submissions written and validated without the leaderboards' toolkits.

``navsim`` writes NAVSIM's ``submission.pkl`` (v1.1, and v2's two-stage navhard format); ``wod_e2e`` writes
WOD-E2E's ``E2EDChallengeSubmission`` shards and the tar.gz to upload. Both read ``predictions.parquet`` and the
converted data folder (for the tokens / frame names a split must cover), never a model, and refuse to write a file
the server would reject, naming why. See docs/submitting.md.
"""
