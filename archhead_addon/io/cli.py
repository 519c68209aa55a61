"""How every command line reports bad input: `warning:` lines, one `error:` line, exit 2;
and Ctrl-C (or a backend's cancel): one `interrupted` line, exit 130, as a shell reports it."""

from __future__ import annotations

import sys
import warnings
from collections.abc import Callable

from .errors import InputError, InputWarning


def run_command(command: Callable[[], int | None]) -> int:
    """Run `command`; input warnings print as they come, an InputError ends it with status 2."""
    with warnings.catch_warnings():
        warnings.simplefilter("always", InputWarning)
        warnings.showwarning = lambda message, *rest: print(f"warning: {message}", file=sys.stderr)
        try:
            return command() or 0
        except InputError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        except KeyboardInterrupt:
            print("interrupted", file=sys.stderr)
            return 130
