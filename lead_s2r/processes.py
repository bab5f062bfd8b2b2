"""Worker processes that do not outlive the process that started them.

A driver killed by SIGKILL (the OOM killer, a scheduler's time limit) runs no clean-up, and ``daemon=True`` only acts
on a normal exit: its spawned workers would keep converting into a folder nobody finishes, holding memory and files.
Each worker therefore watches its parent's pid from a daemon thread and ends itself when it changes (the orphan was
re-parented). Polling ``os.getppid`` is portable, where Linux's ``PR_SET_PDEATHSIG`` is not.
"""

import os
import threading
import time

#: Seconds between two looks at the parent; a worker outlives a killed driver by at most this.
PARENT_POLL_S = 0.2


def exit_with_parent(parent: int) -> None:
    """End this process as soon as ``parent`` is no longer its parent; call it first thing in a worker.

    Also usable as a pool ``initializer`` (``initargs=(os.getpid(),)``). The exit is immediate (``os._exit``):
    whatever the worker was writing is left partial, for the resuming run to drop.
    """

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(PARENT_POLL_S)
        os._exit(1)

    threading.Thread(target=watch, name="exit-with-parent", daemon=True).start()
