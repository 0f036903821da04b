"""The one way a command-line tool of this package ends: its exit status and its error line.

``sys.exit(run_main(main))`` runs ``main()`` and maps what escapes it: an :class:`InputError` (the user's to fix)
prints ``error: <message>`` and exits with :data:`EXIT_USAGE`; any other :class:`AgiprobotError` prints
``error: internal error: <message>`` and exits with :data:`EXIT_INTERNAL`; an ``OSError`` (a folder that cannot be
written, a full disk) prints ``error: <message>`` and exits with :data:`EXIT_USAGE`; Ctrl-C exits with
:data:`EXIT_INTERRUPTED`. Anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import sys
from collections.abc import Callable

from agiprobot_measurement.errors import AgiprobotError, is_input_error

__all__ = ["EXIT_INTERNAL", "EXIT_INTERRUPTED", "EXIT_OK", "EXIT_USAGE", "run_main"]

EXIT_OK = 0
#: a failure that is not the user's input (a solver, a device)
EXIT_INTERNAL = 1
#: bad input: a file, an option, an existing output without --overwrite
EXIT_USAGE = 2
#: interrupted with Ctrl-C
EXIT_INTERRUPTED = 130


def run_main(main: Callable[[], int | None], prog: str = "") -> int:
    """``main()``'s exit status (None counts as :data:`EXIT_OK`), or the status of the package error that ended
    it, after one ``[prog: ]error: ...`` line on stderr."""
    prefix = f"{prog}: " if prog else ""
    try:
        status = main()
    except AgiprobotError as exc:
        if is_input_error(exc):
            print(f"{prefix}error: {exc}", file=sys.stderr, flush=True)
            return EXIT_USAGE
        print(f"{prefix}error: internal error: {exc}", file=sys.stderr, flush=True)
        return EXIT_INTERNAL
    except OSError as exc:  # the user's file system: permissions, a full disk
        print(f"{prefix}error: {exc}", file=sys.stderr, flush=True)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print(f"{prefix}interrupted", file=sys.stderr, flush=True)
        return EXIT_INTERRUPTED
    return EXIT_OK if status is None else int(status)
