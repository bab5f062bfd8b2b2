"""GTRS's vocabulary targets on disk: a pickle ``{token: {metric: float16[V]}}`` (NAVSIM scene token -> GTRS metric
name -> one value per vocabulary entry), the layout SimScale's ``gen_vocab_score.py`` writes and GTRS's training code
loads (``navtrain_8192.pkl``). A run output like predictions, read by two layers, so its one owner lives here:
``lead-s2r vocab score`` writes it, the data module reads it (``SourceSpec.vocab_scores``), without running code
(:mod:`~lead_s2r.formats.restricted_pickle`)."""

import pickle
from pathlib import Path

import numpy as np

from lead_s2r.errors import UserError
from lead_s2r.formats import restricted_pickle

#: GTRS's metric names of EPDMS targets, in SimScale's order (``pdm_score``: the final score)
EPDMS_NAMES = (
    "no_at_fault_collisions",
    "drivable_area_compliance",
    "driving_direction_compliance",
    "traffic_light_compliance",
    "ego_progress",
    "time_to_collision_within_bound",
    "lane_keeping",
    "history_comfort",
    "pdm_score",
)
#: the same for PDMS v1.1 targets: NC, DAC, DDC, EP, TTC, v1.1's comfort and the score (no TLC, LK or HC)
PDMS_NAMES = (*EPDMS_NAMES[:3], *EPDMS_NAMES[4:6], "comfort", EPDMS_NAMES[-1])
Targets = dict[str, dict[str, np.ndarray]]


def targets_bytes(targets: Targets) -> bytes:
    """The pickle of ``targets`` (arrays cast to float16), protocol 4: the same targets give the same bytes."""
    cast = {
        token: {name: np.asarray(v, np.float16) for name, v in columns.items()} for token, columns in targets.items()
    }
    return pickle.dumps(cast, protocol=4)


def read_targets(path: Path) -> Targets:
    """The targets in ``path``; a file of another layout is a UserError naming it."""
    try:
        with open(path, "rb") as file:
            targets = restricted_pickle.load(file)
    except FileNotFoundError:
        raise UserError(f"{path}: no such file; give the vocab_scores.pkl of lead-s2r vocab score") from None
    except (pickle.UnpicklingError, EOFError, ValueError) as err:
        raise UserError(f"{path}: not a vocabulary-targets pickle ({err})") from None
    if not isinstance(targets, dict):
        raise UserError(f"{path}: not a vocabulary-targets pickle (a {type(targets).__name__}, not a dict by token)")
    sizes = set()
    for token, columns in targets.items():
        arrays = list(columns.values()) if isinstance(columns, dict) and columns else [None]
        if not isinstance(token, str) or not all(isinstance(a, np.ndarray) and a.ndim == 1 for a in arrays):
            raise UserError(f"{path}: entry {token!r} is not {{metric: 1-D array}}; not a vocabulary-targets pickle")
        sizes |= {len(array) for array in arrays}
    if len(sizes) > 1:
        raise UserError(f"{path}: arrays of {sorted(sizes)} entries; one vocabulary has one size")
    return targets
