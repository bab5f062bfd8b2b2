"""Adapters and scorers are found through entry points, so a third-party package adds one without touching ours."""

import inspect
from abc import ABC, abstractmethod
from collections.abc import Iterator
from dataclasses import dataclass, field
from importlib.metadata import entry_points
from pathlib import Path
from typing import Any, ClassVar

from lead_s2r.errors import UserError

ADAPTER_GROUP = "lead_s2r.adapters"
SCORER_GROUP = "lead_s2r.scorers"


@dataclass(frozen=True)
class LogRef:
    """A cheap, picklable handle on one log; ``iter_samples`` does the heavy I/O in a worker."""

    log_id: str
    split: str
    path: str
    extra: dict[str, Any] = field(default_factory=dict, hash=False, compare=False)


class Adapter(ABC):
    """Turns one raw dataset into schema v1 samples. Subclasses set ``name``, ``version`` and ``extras``."""

    name: ClassVar[str]
    version: ClassVar[str]
    #: pip extra that brings this adapter's optional dependencies (shown by ``lead-s2r adapters``).
    extras: ClassVar[str | None] = None

    @abstractmethod
    def list_logs(self, src: Path) -> list[LogRef]:
        """All logs under ``src`` in a stable order."""

    @abstractmethod
    def iter_samples(self, log: LogRef) -> Iterator[dict[str, Any]]:
        """Samples of one log, in frame order, as schema v1 dicts."""

    def describe(self) -> dict[str, Any]:
        """Dataset facts written to ``info.json`` (rates, horizons, cameras...)."""
        return {}

    def options(self) -> dict[str, Any]:
        """The constructor options that shape the samples, recorded with a conversion: resuming into a folder
        converted with other options is refused. Default: every ``__init__`` parameter the adapter keeps as a
        same-named attribute; override it to add renamed ones or to drop those that only change speed."""
        names = inspect.signature(type(self).__init__).parameters
        return {name: getattr(self, name) for name in names if name != "self" and hasattr(self, name)}

    def bad_records(self) -> list[dict[str, Any]]:
        """Records :meth:`list_logs` found unreadable and left out, each with an ``error`` naming file and place;
        a conversion reports them in ``errors.jsonl`` and its exit status."""
        return []


class SkipLog(Exception):
    """Raised by an adapter for a log it deliberately leaves out (e.g. a failed CARLA route); not an error."""


class RegistryError(UserError, LookupError):
    """An unknown name or an entry point that cannot be loaded."""


def _group(group: str) -> dict[str, Any]:
    return {ep.name: ep for ep in entry_points(group=group)}


def names(group: str = ADAPTER_GROUP) -> list[str]:
    """Registered names in an entry-point group, sorted."""
    return sorted(_group(group))


def load(name: str, group: str = ADAPTER_GROUP) -> Any:
    """The object registered as ``name``; a clear error lists what is registered."""
    eps = _group(group)
    if name not in eps:
        raise RegistryError(f"no {group} entry named {name!r}; registered: {', '.join(sorted(eps)) or 'none'}")
    try:
        return eps[name].load()
    except ImportError as err:
        raise RegistryError(
            f"{group} entry {name!r} cannot be imported ({err}); its optional dependencies may be missing: "
            "pip install 'lead-s2r[all]'"
        ) from err


def get_adapter(name: str, **options: Any) -> Adapter:
    """Instantiate the adapter registered as ``name`` with its options."""
    return load(name, ADAPTER_GROUP)(**options)


def missing_requirements(extra: str, distribution: str = "lead-s2r") -> list[str]:
    """The requirements of ``distribution``'s extra ``extra`` that are not installed here (those whose environment
    marker excludes this Python count as met), so ``lead-s2r adapters`` can say which extras work."""
    from importlib.metadata import PackageNotFoundError, requires, version

    from packaging.requirements import Requirement

    missing = []
    for line in requires(distribution) or []:
        requirement = Requirement(line)
        marker = requirement.marker
        if marker is None or not marker.evaluate({"extra": extra}) or marker.evaluate({"extra": ""}):
            continue  # not part of this extra, or not for this Python
        try:
            version(requirement.name)
        except PackageNotFoundError:
            missing.append(requirement.name)
    return missing
