"""What each source supervises: the ``supervise:`` config, its task groups and the sim-to-real default."""

from collections.abc import Collection, Mapping

from lead_s2r.models.inputs import PERCEPTION_TASKS, PLANNING_TASKS, Batch
from lead_s2r.training.loss_table import TASK_TARGETS

GROUPS: dict[str, frozenset[str]] = {"planning": PLANNING_TASKS, "perception": PERCEPTION_TASKS}

#: The paper's sim-to-real setting: CARLA teaches perception only, real data teaches driving.
SIM_TO_REAL: dict[str, list[str]] = {
    "carla": ["perception"],
    "navsim": ["planning", "perception"],
    "wod": ["planning"],
}


def active_tasks(
    source: str, batch: Batch, model_tasks: frozenset[str], supervise: Mapping[str, Collection[str]]
) -> frozenset[str]:
    """Loss terms to compute for one source's batch: group entries ("planning", "perception") take the tasks the model
    has for this source and the batch carries targets for; an explicitly named task must be producible and labelled, or
    this raises naming what is missing. A source missing from ``supervise`` supervises nothing."""
    grouped: set[str] = set()
    named: set[str] = set()
    for entry in supervise.get(source, ()):
        if entry in GROUPS:
            grouped |= GROUPS[entry]
        elif entry in TASK_TARGETS:
            named.add(entry)
        else:
            raise ValueError(f"supervise: unknown entry {entry!r}; use {sorted(GROUPS)} or {sorted(TASK_TARGETS)}")
    for task in named:
        if task not in model_tasks:
            raise ValueError(f"supervise[{source!r}] names {task!r}, which the model has no head for on {source!r}")
        if TASK_TARGETS[task] not in batch:
            raise KeyError(f"supervise[{source!r}] names {task!r} but the batch has no {TASK_TARGETS[task]!r}")
    labelled = {t for t in grouped & model_tasks if TASK_TARGETS[t] in batch}
    return frozenset(labelled | named)
