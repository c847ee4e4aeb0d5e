"""A byte-weighed LRU (cachetools) for GL objects: what it evicts is released.

One entry larger than the whole budget is still kept (a render needs it) but alone: the rest
is released, and the big one goes when the next entry arrives.
"""
from __future__ import annotations

from cachetools import LRUCache


class ReleasingLRU(LRUCache):
    def __init__(self, maxsize: int, getsizeof=None):
        super().__init__(maxsize, getsizeof)
        self.evictions = 0
        self._big: tuple | None = None  # (key, value) over the budget, kept outside the LRU

    def __getitem__(self, key):
        if self._big is not None and self._big[0] == key:
            return self._big[1]
        return super().__getitem__(key)

    def __contains__(self, key) -> bool:
        return (self._big is not None and self._big[0] == key) or super().__contains__(key)

    def __setitem__(self, key, value) -> None:
        self._drop_big()
        try:
            super().__setitem__(key, value)
        except ValueError:  # larger than the budget by itself
            self.clear()
            self._big = (key, value)

    def reweigh(self, key) -> None:
        """An entry's size changed (more of it uploaded): weigh it again, keeping it."""
        if key in self and not (self._big is not None and self._big[0] == key):
            value = super().pop(key)  # __delitem__: not an eviction, nothing released
            self[key] = value

    def replace(self, key, value) -> None:
        """`key`'s entry released and `value` put in its place."""
        if key in self and not (self._big is not None and self._big[0] == key):
            super().pop(key).release()  # __delitem__: not counted as an eviction
        self[key] = value  # a big entry of this key is released by __setitem__

    def get(self, key, default=None):
        return self[key] if key in self else default

    def popitem(self):
        key, value = super().popitem()
        value.release()
        self.evictions += 1
        return key, value

    def clear(self) -> None:
        while len(self):
            self.popitem()
        self._drop_big()

    def values_all(self) -> list:
        return list(self.values()) + ([self._big[1]] if self._big else [])

    def _drop_big(self) -> None:
        if self._big is not None:
            self._big[1].release()
            self._big = None
            self.evictions += 1
