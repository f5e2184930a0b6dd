"""Pull sources whose samples sit on a known timeline (replays, synthetic gaze).

Sample ``i`` has an offset ``offset(i)`` seconds from the start of its timeline. With pacing
(``speed`` a positive number) the source is anchored at ``t0 = clock()`` when opened and sample
``i`` becomes available at ``t0 + offset(i) / speed``, which is also its timestamp; `read()` sleeps
until then and `latest()` returns the newest sample already due -- no thread, so an injected clock
makes it fully deterministic. Without pacing (``speed=None``) samples come as fast as they are read
and keep their own timeline's timestamps (``start_time + offset(i)``).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

from ._samples import GazeSample, HeadPose
from ._source import Clock, Source


class PacedSource(Source):
    """Subclasses implement `_offset(i)`, `_sample(i, timestamp)`, `_count()` (None: endless) and
    may override `_skip(i)` (True for samples to leave out, e.g. a simulated dropout)."""

    def __init__(
        self,
        *,
        speed: float | None = 1.0,
        clock: Clock = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
        start_time: float = 0.0,
    ):
        super().__init__(clock=clock)
        if speed is not None and not (math.isfinite(speed) and speed > 0):
            raise ValueError(f"{type(self).__name__}: speed must be a positive number or None, got {speed}")
        self.speed = speed
        self.sleep = sleep
        self.start_time = start_time
        self._t0 = 0.0
        self._next = 0
        self._last: GazeSample | HeadPose | None = None

    # subclass hooks
    def _offset(self, i: int) -> float:
        raise NotImplementedError

    def _sample(self, i: int, timestamp: float):
        raise NotImplementedError

    def _count(self) -> int | None:
        raise NotImplementedError

    def _skip(self, i: int) -> bool:
        return False

    def _index_at(self, elapsed: float) -> int:
        """Largest index whose offset is <= elapsed (-1 if none); subclasses may speed this up."""
        lo, hi = -1, self._count()
        if hi is None:
            hi = 1
            while self._offset(hi) <= elapsed:
                hi *= 2
        while hi - lo > 1:
            mid = (lo + hi) // 2
            if self._offset(mid) <= elapsed:
                lo = mid
            else:
                hi = mid
        return lo

    # lifecycle
    def _open(self) -> None:
        self._t0 = self.clock()
        self._next = 0

    def _close(self) -> None:
        pass

    @property
    def exhausted(self) -> bool:
        count = self._count()
        return self._closed or (count is not None and self._next >= count)

    def _due(self, i: int) -> float:
        if self.speed is None:  # unpaced: samples are due at once
            raise ValueError("an unpaced source has no due times")
        return self._t0 + self._offset(i) / self.speed

    def _stamp(self, i: int) -> float:
        return self._due(i) if self.speed is not None else self.start_time + self._offset(i)

    def read(self, timeout: float | None = None):
        self._require_open()
        count = self._count()
        while not self._closed and (count is None or self._next < count) and self._skip(self._next):
            self._next += 1
        if self._closed or (count is not None and self._next >= count):
            return None
        i = self._next
        if self.speed is not None:
            wait = self._due(i) - self.clock()
            if wait > 0:
                if timeout is not None and wait > timeout:
                    self.sleep(timeout)
                    return None
                self.sleep(wait)
        self._next = i + 1
        sample = self._corrected(self._sample(i, self._stamp(i)))
        self._last = sample
        self.status.samples += 1
        return sample

    def drain(self) -> list:
        """With pacing: every sample already due but not yet read, in order (so a per-frame caller
        sees each sample once). Without pacing nothing is 'received' until read: returns []."""
        if not self.is_open or self.speed is None:
            return []
        out = []
        count = self._count()
        now_index = self._index_at((self.clock() - self._t0) * self.speed)
        while self._next <= now_index and (count is None or self._next < count):
            i = self._next
            self._next += 1
            if self._skip(i):
                continue
            sample = self._corrected(self._sample(i, self._stamp(i)))
            self._last = sample
            self.status.samples += 1
            out.append(sample)
        return out

    def latest(self):
        if not self.is_open:
            return None
        if self.speed is None:
            return self._last
        i = self._index_at((self.clock() - self._t0) * self.speed)
        count = self._count()
        if count is not None:
            i = min(i, count - 1)
        while i >= 0 and self._skip(i):
            i -= 1
        if i < 0:
            return None
        return self._corrected(self._sample(i, self._stamp(i)))
