"""Results kept within a budget of bytes, the oldest forgotten first.

A diagnosis asks again for what it has just had: the screen's views score the same
simulations, a screen's candidates start from one simulation, a fit's step reuses the residual
it has just scored. The simulator keeps its latest simulations and a calibrator its latest
residuals in a :class:`Memo` each, so that memory stays bounded however long the search.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable
from typing import Generic, TypeVar

K = TypeVar("K", bound=Hashable)
V = TypeVar("V")


class Memo(Generic[K, V]):
    """Values by key, in the order they were kept; beyond ``budget`` bytes the oldest go.

    Parameters
    ----------
    budget : int
        Bytes kept at most (the latest value is kept whatever its size).
    size : callable
        The bytes a value holds.
    forgotten : callable, optional
        Called with each value as it is forgotten.
    """

    def __init__(
        self,
        budget: int,
        size: Callable[[V], int],
        forgotten: Callable[[V], None] | None = None,
    ) -> None:
        self.budget = budget
        self._size = size
        self._forgotten = forgotten
        self._values: dict[K, V] = {}
        self.bytes = 0

    def __contains__(self, key: K) -> bool:
        return key in self._values

    def __len__(self) -> int:
        return len(self._values)

    def __getitem__(self, key: K) -> V:
        return self._values[key]

    def get(self, key: K) -> V | None:
        """The value kept for ``key``, or None."""
        return self._values.get(key)

    def keep(self, key: K, value: V) -> None:
        """Keep ``value`` as the latest, forgetting the oldest beyond the budget."""
        if key in self._values:
            self.bytes -= self._size(self._values.pop(key))
        self._values[key] = value
        self.bytes += self._size(value)
        while self.bytes > self.budget and len(self._values) > 1:
            old = self._values.pop(next(iter(self._values)))
            self.bytes -= self._size(old)
            if self._forgotten is not None:
                self._forgotten(old)
