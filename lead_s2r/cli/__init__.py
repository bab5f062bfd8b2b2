"""The ``lead-s2r`` command line: one module per verb group, each adding its verbs with ``add_verbs``.

Every mistake a user can fix is a :class:`~lead_s2r.errors.UserError`, raised wherever it is found; ``main()`` prints it
as one line with exit status 2 (``--debug`` anywhere on the line shows the traceback). argparse's own mistakes are
routed through the same path, so every verb fails alike. Inputs are checked before any output folder is created.
"""

import argparse
import os
import sys
from typing import NoReturn

from lead_s2r import __version__
from lead_s2r.cli import closed_loop, data, demo, report, scoring, serve, submit, training, vocab
from lead_s2r.errors import UserError

LIGHTNING_VERBS = ("fit", "validate", "test", "predict")
DEBUG_FLAG = "--debug"
USER_ERROR_STATUS = 2
#: A closed stdout: the status a shell gives a process ended by SIGPIPE (128 + 13).
BROKEN_PIPE_STATUS = 141
#: A shell's status for a command stopped by SIGINT (128 + 2).
INTERRUPTED_STATUS = 130
#: The verb groups, in the order ``lead-s2r --help`` lists them.
VERB_GROUPS = (data, scoring, vocab, submit, closed_loop, serve, report, training, demo)


class _Parser(argparse.ArgumentParser):
    """argparse whose mistakes are :class:`UserError`, so they print as one line like every other."""

    def error(self, message: str) -> NoReturn:
        raise UserError(f"{self.prog}: {message} (see {self.prog} --help)")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="lead-s2r",
        description="Convert driving datasets to one schema, train, score and make the paper's tables.",
        epilog="Training: lead-s2r fit|validate|test|predict --config recipes/... (LightningCLI; see --help there).",
    )
    parser.add_argument("--version", action="version", version=f"lead-s2r {__version__}")
    parser.add_argument(DEBUG_FLAG, action="store_true", help="show the traceback of a user error (any position)")
    verbs = parser.add_subparsers(dest="verb", required=True, metavar="VERB")
    for group in VERB_GROUPS:
        group.add_verbs(verbs)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run one verb; a :class:`UserError` is one line on stderr and exit status 2 (its traceback with --debug)."""
    from_shell = argv is None
    argv = list(sys.argv[1:] if argv is None else argv)
    debug = DEBUG_FLAG in argv
    argv = [arg for arg in argv if arg != DEBUG_FLAG]
    if from_shell:  # LightningCLI reads sys.argv itself (and warns when given both)
        sys.argv[1:] = argv
    try:
        status = _run(argv, from_shell)
        sys.stdout.flush()  # here, where a closed pipe is caught, not at the interpreter's exit
        return status
    except UserError as err:
        if debug:
            raise
        print(f"error: {err.one_line()}", file=sys.stderr)
        return USER_ERROR_STATUS
    except BrokenPipeError:  # `lead-s2r ... | head`: the reader has all it wanted
        _quiet_stdout()
        return BROKEN_PIPE_STATUS
    except KeyboardInterrupt:  # Ctrl-C: one line; files are written whole or not at all, so what was written stays
        if debug:
            raise
        print("interrupted", file=sys.stderr)
        return INTERRUPTED_STATUS


def _quiet_stdout() -> None:
    """Point stdout at /dev/null, so the interpreter's final flush of the closed pipe raises nothing either."""
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, sys.stdout.fileno())
    os.close(devnull)


def _run(argv: list[str], from_shell: bool) -> int:
    if argv and argv[0] in LIGHTNING_VERBS:
        from lead_s2r.training.cli import run_lightning_cli

        run_lightning_cli(None if from_shell else argv)
        return 0
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    if args.verb == "convert":
        return data.cmd_convert(args, extra)
    if extra:
        parser.error(f"unrecognized arguments: {' '.join(extra)}")
    return args.run(args)
