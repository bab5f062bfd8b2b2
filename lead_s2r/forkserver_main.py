"""Preloaded by the forkserver of :class:`lead_s2r.processes.ProcessExecutor`: imports the caller's main module
there, once, as a spawned worker would (as ``__mp_main__``), so the workers forked from it find it imported and do
not import it again each (a script that imports torch cost every worker seconds before its first job).

CPython's own ``set_forkserver_preload(["__main__"])`` is meant to do this, but its forkserver never receives the
script (3.11-3.13 ask spawn's preparation data for ``main_path``, which spawn names ``init_main_from_path``), so the
driver passes how ``__main__`` was started in :data:`~lead_s2r.processes.FORKSERVER_MAIN` and this module hands it
to ``multiprocessing.spawn.prepare``, the function spawned children run. A script that starts workers without an
``if __name__ == "__main__":`` guard gets multiprocessing's own error, as with spawn.
"""

import json
import os
from multiprocessing import process, spawn

from lead_s2r.processes import FORKSERVER_MAIN


def import_callers_main() -> None:
    main = json.loads(os.environ.get(FORKSERVER_MAIN, "{}"))
    if not main:
        return
    current = process.current_process()
    current._inheriting = True  # type: ignore[attr-defined]  # what CPython's forkserver sets around its preload
    try:
        spawn.prepare(main)
    finally:
        del current._inheriting  # type: ignore[attr-defined]


import_callers_main()
