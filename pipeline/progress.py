"""Progress bars (rich) that ``--quiet`` silences; they draw on stderr so stdout stays clean."""
from __future__ import annotations

from contextlib import contextmanager

from rich.console import Console
from rich.progress import (BarColumn, MofNCompleteColumn, Progress, ProgressColumn, TextColumn, TimeElapsedColumn,
                           TimeRemainingColumn)
from rich.text import Text

__all__ = ["progress_bar", "console"]

console = Console(stderr=True)


class _Silent:
    def add_task(self, *a, **k):
        return 0

    def advance(self, *a, **k):
        pass

    def update(self, *a, **k):
        pass


class _InfoColumn(ProgressColumn):
    """A task's optional ``info`` field: a task added without one shows nothing (rich's
    ``_InfoColumn()`` raises KeyError while drawing, after the work is done)."""

    def render(self, task) -> Text:
        return Text(str(task.fields.get("info", "")))


@contextmanager
def progress_bar(quiet: bool = False):
    """Yield an object with rich's ``add_task`` / ``advance`` / ``update`` API."""
    if quiet:
        yield _Silent()
        return
    with Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                  _InfoColumn(), TimeElapsedColumn(), TimeRemainingColumn(),
                  console=console, transient=False) as p:
        yield p
