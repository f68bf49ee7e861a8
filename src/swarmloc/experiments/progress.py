"""Progress bars of the commands that run longer than a few seconds: rich, on stderr (stdout keeps the tables and
the JSON a caller may pipe on), removed when done."""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from typing import Any

__all__ = ["Tick", "no_tick", "progress_bar", "stderr_console", "steps"]

Tick = Callable[[str], None]
"""``tick(label)``: one step done; ``label`` says what runs next."""


def no_tick(label: str) -> None:
    """The :data:`Tick` of a run without a progress bar."""


def stderr_console() -> Any:
    """A rich console on stderr."""
    from rich.console import Console

    return Console(stderr=True)


def _bar() -> Any:
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    return Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                    transient=True, console=stderr_console())  # fmt: skip


@contextlib.contextmanager
def progress_bar(enabled: bool) -> Iterator[Callable[[str], Callable[[int, int | None], None]] | None]:
    """Yields ``start(description) -> callback(done, total)``, one bar per ``start`` (``total`` None: not known);
    None when disabled."""
    if not enabled:
        yield None
        return
    with _bar() as bar:

        def start(description: str) -> Callable[[int, int | None], None]:
            task = bar.add_task(description, total=None)

            def cb(done: int, total: int | None) -> None:
                bar.update(task, completed=done, total=total)

            return cb

        yield start


@contextlib.contextmanager
def steps(enabled: bool, total: int, description: str) -> Iterator[Tick]:
    """One bar over ``total`` steps: yields :data:`Tick` (:func:`no_tick` when disabled)."""
    if not enabled:
        yield no_tick
        return
    with _bar() as bar:
        task = bar.add_task(description, total=total)

        def tick(label: str) -> None:
            bar.update(task, advance=1, description=f"{description}: {label}" if label else description)

        yield tick
