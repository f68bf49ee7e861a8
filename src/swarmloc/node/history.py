"""A node's history: its stamped entries in key order, the filter state after each, replay and horizon.

The state after an entry is the state after the entry before it, every robot the entry involves predicted to the
entry's stamp with the command in force, then the entry applied. So a late input is inserted at its key and the
entries after it are re-applied (replayed); the result does not depend on the order the inputs came in. Entries
older than the horizon are forgotten, the state after the last of them becoming the **base**.

A filter whose commands only predict (``lazy=True``) leaves the state of a command entry appended in order
uncomputed; a run of such entries is computed at once when a state is needed (:meth:`History.state_at`, one call
of ``advance_run``: the filter's ``_advance_commands``, which may preintegrate the run), giving the same result as
computing each.
"""

from __future__ import annotations

from bisect import bisect_left
from collections.abc import Callable, Sequence
from typing import Any

from swarmloc.messages import Message
from swarmloc.node.keys import Entry, Key

__all__ = ["PRUNE_EVERY", "History"]

PRUNE_EVERY = 64
"""Inputs between two prunings of the history (pruning costs a bisection and a slice)."""

AdvanceRun = Callable[[Any, Sequence[Entry]], Any]
Apply = Callable[[Any, Entry], tuple[Any, list[Message], bool]]


class History:
    """Entries in key order (``keys[i]`` is ``entries[i].key``), the base state before them and its key."""

    def __init__(self, advance_run: AdvanceRun, lazy: bool) -> None:
        self.advance_run = advance_run
        self.lazy = lazy
        self.keys: list[Key] = []
        self.entries: list[Entry] = []
        self.base: Any = None
        self.base_key: Key | None = None

    def __len__(self) -> int:
        return len(self.entries)

    def reset(self, base: Any, base_key: Key) -> None:
        """Forget every entry; ``base`` holds at ``base_key``."""
        self.keys.clear()
        self.entries.clear()
        self.base, self.base_key = base, base_key

    def position(self, key: Key) -> int:
        """Where ``key`` is or would be inserted."""
        keys = self.keys
        if not keys or keys[-1] < key:
            return len(keys)
        return bisect_left(keys, key)

    def find(self, key: Key) -> int | None:
        """The position of the entry filed at ``key``, or None."""
        pos = self.position(key)
        return pos if pos < len(self.keys) and self.keys[pos] == key else None

    # ------------------------------------------------------------------------------------------------ states
    def state_at(self, i: int) -> Any:
        """The state after entry ``i`` (the base for ``i < 0``); a run of command entries not computed yet is
        computed by one ``advance_run`` call from the latest state before it."""
        if i < 0:
            return self.base
        entries = self.entries
        s = entries[i].state
        if s is not None:
            return s
        j = i - 1
        while j >= 0 and entries[j].state is None:
            j -= 1
        s = entries[j].state if j >= 0 else self.base
        s = self.advance_run(s, entries[j + 1 : i + 1])
        entries[i].state = s
        return s

    def state_before(self, key: Key) -> Any:
        return self.state_at(bisect_left(self.keys, key) - 1)

    def last_state(self) -> Any:
        return self.state_at(len(self.entries) - 1)

    # ------------------------------------------------------------------------------------------------ changes
    def append(self, entry: Entry) -> None:
        self.keys.append(entry.key)
        self.entries.append(entry)

    def insert(self, pos: int, entry: Entry) -> None:
        self.keys.insert(pos, entry.key)
        self.entries.insert(pos, entry)

    def remove(self, pos: int) -> None:
        del self.keys[pos]
        del self.entries[pos]

    def replay(self, pos: int, apply: Apply) -> tuple[list[Message], int]:
        """Re-apply the entries from ``pos`` on with ``apply(state, entry) -> (state, messages, void)``, removing
        those that became void; returns the messages and the number of entries re-applied after ``pos``."""
        entries = self.entries
        if self.lazy:  # the states after pos are recomputed: none of them may start a lazy run
            for e in entries[pos:]:
                e.state = None
        s = self.state_at(pos - 1)
        replayed = len(entries) - pos - 1
        out: list[Message] = []
        void: list[int] = []
        for i in range(pos, len(entries)):
            e = entries[i]
            if self.lazy:
                if e.kind == "odometry":
                    continue
                s = self.state_at(i - 1)
            s, msgs, is_void = apply(s, e)
            e.state = s
            out += msgs
            if is_void:
                void.append(i)
        for i in reversed(void):
            self.remove(i)
        return out, replayed

    def prune(self, cutoff: float) -> None:
        """Forget the entries stamped before ``cutoff``, the state after the last of them becoming the base."""
        n = bisect_left(self.keys, (cutoff,))
        if n > 0:
            self.base = self.state_at(n - 1)
            self.base_key = self.keys[n - 1]
            del self.entries[:n]
            del self.keys[:n]
