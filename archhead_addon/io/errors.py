"""One error and one warning type for bad input, each naming the file, the key and the problem."""

from __future__ import annotations

import os
import warnings


def _describe(path, key, problem) -> str:
    where = os.fspath(path) if path is not None else "<input>"
    if key is not None:
        where += f": key '{key}'"
    return f"{where}: {problem}"


class InputError(ValueError):
    """Bad input: carries the file, the key (or None) and what was wrong."""

    def __init__(self, path, key, problem: str):
        self.path, self.key, self.problem = path, key, problem
        super().__init__(_describe(path, key, problem))


class InputWarning(UserWarning):
    """Input was used but adjusted (padded, truncated, ...); the text says what was done."""


def warn_input(path, key, problem: str) -> None:
    warnings.warn(InputWarning(_describe(path, key, problem)), stacklevel=3)
