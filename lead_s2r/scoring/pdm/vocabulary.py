"""Every sub-score of a trajectory vocabulary (V entries, thousands) in one scene: the training targets of
Hydra-MDP / GTRS-style planners, exact and in one pass.

``score_vocabulary`` is ``score_proposals`` over the whole vocabulary, with what the scene shares built once
(observation, drivable map with its grid, whose cells classified for one chunk serve the next, red-light polygons)
and the entries simulated in blocks of ``simulation_block`` rows and scored in chunks of ``chunk``, so memory stays
bounded (16,384 entries take well under 2 GB). Row v is bit for bit ``score_proposals(scene, vocabulary[v:v + 1],
...)``: every step of the pipeline computes a row without looking at the others (``elementwise``), so a block's or
a chunk's neighbours change nothing; ``tests/test_vocabulary.py`` checks it on random entries, every column.

EP has two definitions. The default (``progress="pair"``) is NAVSIM's for one agent trajectory: each entry's
progress is normalised over ``[PDM-Closed, entry]``, as ``pdm_score`` scores a submitted trajectory. GTRS's targets
(SimScale's ``gen_vocab_score.py`` calls ``pdm_score_full_v2``, which scores PDM-Closed and all V entries in one
``PDMScorer.score_proposals`` call) normalise over ``[PDM-Closed, entry 0, ..., entry V-1]``: the normaliser is the
largest masked progress of the reference and the whole vocabulary (``progress="vocabulary"``), and the score is
recomputed from that EP. Masking, the 5 m threshold and the formulas are v1.1's or v2.2's as the metric says
(``metrics.ego_progress`` / ``ego_progress_v2``). SimScale's script also turns v2.2's human penalty filter off
(``human_penalty_filter=False``): ``human_filter=False`` does the same; GTRS's targets are
``progress="vocabulary", human_filter=False``.
"""

import numpy as np

from lead_s2r.scoring.pdm import epdms
from lead_s2r.scoring.pdm.map_flags import VOCABULARY_GRID, DrivableMap
from lead_s2r.scoring.pdm.metrics import ego_progress, ego_progress_v2, pdms_v11
from lead_s2r.scoring.pdm.observation import V2_STEPS, log_observation
from lead_s2r.scoring.pdm.scene import PDMScene
from lead_s2r.scoring.pdm.score import (
    EPDMS_METRIC,
    INTERVAL_S,
    METRIC,
    METRICS,
    human_trajectory,
    score_proposals,
    simulate_rows,
)
from lead_s2r.scoring.pdm.traffic_lights import red_light_polygons

#: entries scored together: big enough that numpy's per-call cost vanishes, small enough that a chunk's map points
#: and TTC queries (chunk x 41 x 6 and x 4) stay near the cache (1,024 is slower than 512 here, 1 MB of L2 per core)
CHUNK = 512
#: entries simulated together: the simulation's ~3,000 numpy calls per block cost less per entry over more rows
SIMULATION_BLOCK = 1024
PROGRESS_PAIR = "pair"
PROGRESS_VOCABULARY = "vocabulary"
PROGRESS_MODES = (PROGRESS_PAIR, PROGRESS_VOCABULARY)
#: GTRS's vocabulary layout: (V, 40, 3) poses (x, y, heading) every 0.1 s
GTRS_POSES = 40
GTRS_INTERVAL_S = 0.1


def check_vocabulary(vocabulary: np.ndarray, name: str = "vocabulary") -> np.ndarray:
    """``vocabulary`` as float64 ``(V, K, 3)`` with only finite values, or a ValueError naming what is wrong."""
    array = np.asarray(vocabulary)
    if array.ndim != 3 or array.shape[-1] != 3 or array.shape[0] < 1 or array.shape[1] < 1:
        raise ValueError(f"{name}: expected (V, K, 3) ego-frame poses (x, y, heading), got shape {array.shape}")
    if not np.issubdtype(array.dtype, np.floating):
        raise ValueError(f"{name}: expected floating-point poses, got dtype {array.dtype}")
    bad = ~np.isfinite(array).all(axis=(1, 2))
    if bad.any():
        raise ValueError(
            f"{name}: {int(bad.sum())} entries hold NaN or inf (first: entry {int(np.argmax(bad))}); remove them"
        )
    return array.astype(np.float64)


def score_vocabulary(
    scene: PDMScene,
    vocabulary: np.ndarray,
    interval: float,
    reference: np.ndarray,
    metric: str = METRIC,
    *,
    progress: str = PROGRESS_PAIR,
    human_filter: bool = True,
    chunk: int = CHUNK,
    simulation_block: int = SIMULATION_BLOCK,
) -> dict[str, np.ndarray]:
    """``metric`` of every entry of ``vocabulary (V, K, 3)`` (ego-frame poses at ``interval * (k + 1)``): one
    ``(V,)`` array per column of ``score_proposals`` (``COLUMNS`` or ``EPDMS_COLUMNS``), row v equal to scoring
    entry v alone. ``progress`` and ``human_filter``: the module docstring. EC needs a previous frame and stays NaN.
    ``simulation_block`` and ``chunk`` change speed and memory only (a row's bits are its own)."""
    if metric not in METRICS:
        raise ValueError(f"metric {metric!r} is not scored here; score_vocabulary computes {' and '.join(METRICS)}")
    if progress not in PROGRESS_MODES:
        raise ValueError(f"progress {progress!r}: choose {' or '.join(PROGRESS_MODES)}")
    if chunk < 1 or simulation_block < 1:
        raise ValueError(f"chunk {chunk}, simulation_block {simulation_block}: give at least 1 entry to each")
    vocabulary = check_vocabulary(vocabulary)
    arguments = {"drivable_map": DrivableMap.from_scene(scene, *VOCABULARY_GRID)}
    if metric == EPDMS_METRIC:
        arguments |= {
            "observation": log_observation(scene, V2_STEPS, replay=True),
            "red_lights": red_light_polygons(scene, V2_STEPS, INTERVAL_S),
        }
    else:
        arguments["observation"] = log_observation(scene)
    wants_masked = progress == PROGRESS_VOCABULARY
    arguments |= {"with_masked_progress": wants_masked, "human_filter": human_filter}
    human = human_trajectory(scene) if metric == EPDMS_METRIC and human_filter else None
    parts = []
    for block in range(0, len(vocabulary), simulation_block):
        entries = vocabulary[block : block + simulation_block]
        states = simulate_rows(scene, entries, interval, reference, human)
        # a chunk's rows: the reference, its entries, and the human trajectory's row where there is one
        reference_row, entry_rows, human_row = states[:1], states[1 : len(entries) + 1], states[len(entries) + 1 :]
        for start in range(0, len(entries), chunk):
            rows = np.concatenate([reference_row, entry_rows[start : start + chunk], human_row])
            part = entries[start : start + chunk]
            parts.append(score_proposals(scene, part, interval, reference, metric, **arguments, simulated=rows))
    columns = {name: np.concatenate([part[name] for part in parts]) for name in parts[0]}
    return _normalised_over_vocabulary(columns, metric) if wants_masked else columns


def _normalised_over_vocabulary(columns: dict[str, np.ndarray], metric: str) -> dict[str, np.ndarray]:
    """The columns with EP (and the score) recomputed over one group: the reference, whose masked progress a
    multiplier of 1 keeps as it is, and every entry."""
    raw = np.concatenate([columns.pop("reference_masked_progress_m")[:1], columns["progress_m"]])
    multiplier = np.concatenate([[1.0], columns.pop("progress_multiplier")])
    ep, normaliser = (ego_progress_v2 if metric == EPDMS_METRIC else ego_progress)(raw, multiplier, None)
    out = columns | {epdms.EP: ep[1:], "ep_normaliser_m": normaliser[1:]}
    if metric == EPDMS_METRIC:
        out["score"] = epdms.epdms(out)
        return out
    out["score"] = pdms_v11(
        out[epdms.NC], out[epdms.DAC], out[epdms.EP], out[epdms.TTC], out["comfort"], out[epdms.DDC]
    )
    return out
