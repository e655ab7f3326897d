"""Commands whose inputs arrive on separate topics, assembled into one command per instant.

A rig that publishes each valve on a topic of its own (two ``std_msgs/msg/Float64``, say)
sends the validator one value at a time; the aligner takes a command as all inputs at one
stamp. :class:`CommandAssembler` groups the values by sample instant (the grid step nearest
to each stamp, counted from the first stamp seen) and hands out one command per instant once
every input has a value for it, or once a value two instants later shows that it will not
come (the missing input then holds its last value, as the valve does; one instant of slack
lets the topics interleave loosely). Commands come out in time
order with the stamp of the group's first value, so the aligner judges the stamp as it
judges any other.
"""

from __future__ import annotations

import math

import numpy as np

from twotank_validation.defaults import NS_PER_S
from twotank_validation.errors import DatumError


class CommandAssembler:
    """Group per-input values into commands, one per sample instant.

    Args:
        n_inputs: number of inputs of a command.
        ts_s: sample period (s).
    """

    def __init__(self, n_inputs: int, ts_s: float) -> None:
        if n_inputs < 1:
            raise DatumError(f"a command needs at least one input, found {n_inputs}")
        if not (math.isfinite(ts_s) and ts_s > 0):
            raise DatumError(f"ts_s must be a positive number of seconds, found {ts_s}")
        self.n_inputs = n_inputs
        self._ts_ns = round(ts_s * NS_PER_S)
        self._t0: int | None = None
        self._held = np.full(n_inputs, np.nan)  # the last value of each input
        # instant -> (stamp of its first value, values (NaN: not yet), seen)
        self._pending: dict[int, tuple[int, np.ndarray, np.ndarray]] = {}
        self._done = -1  # the last instant handed out

    def push(self, index: int, stamp_ns: int, value: float) -> list[tuple[int, np.ndarray]]:
        """One input's value in; the commands it completes out.

        Args:
            index: the input (0 .. n_inputs - 1).
            stamp_ns: its stamp (ns).
            value: its value (model units).

        Returns:
            ``(stamp_ns, (n_inputs,) float)`` commands, in time order.
        """
        if not 0 <= index < self.n_inputs:
            raise DatumError(f"input index {index} is not in 0 .. {self.n_inputs - 1}")
        if self._t0 is None:
            self._t0 = stamp_ns
        k = round((stamp_ns - self._t0) / self._ts_ns)
        if k <= self._done:
            return []  # late for an instant already handed out: the aligner saw it go
        _, values, seen = self._pending.setdefault(
            k, (stamp_ns, np.full(self.n_inputs, np.nan), np.zeros(self.n_inputs, bool))
        )
        values[index] = value
        seen[index] = True
        out: list[tuple[int, np.ndarray]] = []
        for j in sorted(self._pending):
            stamp_j, values_j, seen_j = self._pending[j]
            if not (seen_j.all() or j < k - 1):
                break  # wait for the rest of this instant (one instant of slack for stragglers)
            out.append((stamp_j, self._complete(values_j, seen_j)))
            del self._pending[j]
            self._done = j
        return out

    def flush(self) -> list[tuple[int, np.ndarray]]:
        """The commands still waiting for an input (at the end of a recording)."""
        out = []
        for j in sorted(self._pending):
            stamp_j, values_j, seen_j = self._pending.pop(j)
            out.append((stamp_j, self._complete(values_j, seen_j)))
            self._done = j
        return out

    def _complete(self, values: np.ndarray, seen: np.ndarray) -> np.ndarray:
        self._held = np.where(seen, values, self._held)
        return self._held.copy()
