"""NAVSIM's PDM score (PDMS v1.1, EPDMS v2.2) in plain numpy and shapely: no nuplan-devkit, no torch.

The pipeline mirrors NAVSIM's ``pdm_score``: proposals are interpolated to 10 Hz, tracked by a batched LQR and
propagated by a kinematic bicycle, then scored against the map and the logged agents. Constants and every rule are
in ``docs/metrics.md``; the facts come from NAVSIM's own code (see the module docstrings).
"""

from lead_s2r.scoring.pdm.scene import PDMScene, PreviousFrame
from lead_s2r.scoring.pdm.score import score_proposals, score_states, score_states_v2
from lead_s2r.scoring.pdm.vocabulary import score_vocabulary

__all__ = ["PDMScene", "PreviousFrame", "score_proposals", "score_states", "score_states_v2", "score_vocabulary"]
