"""Per-resolution tables, least recently used out once their bytes pass a bound: the numpy
runtime's (one per precision) and the torch model's (one per device) alike. Training samples
every S from s_min to s_max, so a bound by count rather than bytes made stage 2 rebuild most
of its tables (docs/training_profile.md)."""

from __future__ import annotations

import threading

LEVEL_BYTES = 256 << 20  # the per-S tables kept: a full-size avatar's S = 256 takes 49 MB


class LevelCache:
    """`build(size, kind)`'s tables (a dict of arrays or tensors; `kind` the precision or the
    device), least recently used out once their bytes pass `max_bytes` (the newest always
    stays); `hits`, `misses` and `len()` for tests. Safe to call from several threads
    (`decode_batch`): a table asked for by two at once is built once."""

    def __init__(self, build, max_bytes: int):
        self.build, self.max_bytes = build, int(max_bytes)
        self._levels: dict[tuple, tuple[dict, int]] = {}  # insertion order: least recent first
        self.nbytes = self.hits = self.misses = 0
        self._lock = threading.Lock()

    def __call__(self, size: int, kind) -> dict:
        with self._lock:
            return self._get((int(size), kind))

    def _get(self, key: tuple) -> dict:
        found = self._levels.pop(key, None)
        if found is not None:
            self.hits += 1
        else:
            self.misses += 1
            level = self.build(*key)
            found = (level, sum(getattr(v, "nbytes", 0) for v in level.values()))
            self.nbytes += found[1]
        self._levels[key] = found
        while self.nbytes > self.max_bytes and len(self._levels) > 1:
            self.nbytes -= self._levels.pop(next(iter(self._levels)))[1]
        return found[0]

    def __len__(self) -> int:
        return len(self._levels)

    def clear(self) -> None:
        with self._lock:
            self._levels.clear()
            self.nbytes = 0

    def __getstate__(self) -> dict:  # the tables are rebuilt on use; a lock does not pickle
        return {"build": self.build, "max_bytes": self.max_bytes}

    def __setstate__(self, state: dict) -> None:
        self.__init__(state["build"], state["max_bytes"])
