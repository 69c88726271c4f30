"""Progress of the studies: how many points are left and about how long they
will take (:class:`Eta`), and where a long point's run is (:class:`PointProgress`)."""
from __future__ import annotations

import time
from typing import Callable


class Eta:
    """The points left and, from the mean time of the points run so far, how long
    they will take: ``"3 of 8 point(s) left, about 2 min"`` ("" after the last)."""

    def __init__(self, n: int):
        self.n, self.finished, self.t0 = n, 0, time.perf_counter()

    def done(self) -> str:
        self.finished += 1
        left = self.n - self.finished
        if left <= 0:
            return ""
        per = (time.perf_counter() - self.t0) / self.finished
        return f"{left} of {self.n} point(s) left, about {duration(per * left)}"


def duration(seconds: float) -> str:
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


class PointProgress:
    """A point's ``progress(t, t_end)``: a line every ``EVERY`` seconds of a long
    point (``"[2/5] mu=0.4: t = 1.2 / 3 s, 12 s"``), none for a short one; and its
    set-up's phases (:meth:`phase`): ``"[2/5] mu=0.4: setting up: ..."`` at once."""

    EVERY = 5.0

    def __init__(self, say: Callable[[str], None], head: str):
        self.say, self.head = say, head
        self.t0 = self.last = None

    def phase(self, what: str):
        """``Simulation(on_phase=)``: the point's first line as its set-up begins,
        then a phase only when the last line is ``EVERY`` seconds old."""
        now = time.perf_counter()
        if self.last is None or now - self.last >= self.EVERY:
            self.say(f"{self.head}: {'setting up' if self.last is None else 'set-up'}: {what}")
            self.last = now

    def __call__(self, t: float, t_end: float):
        now = time.perf_counter()
        if self.t0 is None:
            self.t0 = now
            self.last = now if self.last is None else self.last
        if now - self.last >= self.EVERY:
            self.last = now
            self.say(f"{self.head}: t = {t:.3g} / {t_end:g} s, {now - self.t0:.0f} s")
