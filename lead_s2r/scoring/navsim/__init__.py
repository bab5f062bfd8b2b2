"""NAVSIM's scores of predictions on converted NAVSIM samples: ``pdms@navsim-1.1`` (:class:`PDMSScorer`) and
``epdms@navsim-2.2`` (:class:`EPDMSScorer`: one stage, or navhard's two stages where the samples carry the
two-stage mapping). The simulation and the sub-metrics they share are :mod:`lead_s2r.scoring.pdm`.
"""

from lead_s2r.scoring.navsim.epdms_scorer import EPDMSScorer
from lead_s2r.scoring.navsim.pdms_scorer import PDMSScorer

__all__ = ["EPDMSScorer", "PDMSScorer"]
