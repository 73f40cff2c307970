"""Progress for long steps, in a terminal and in logs: a live rich bar when the console is a terminal, else plain
lines (a live bar prints nothing useful to a file or a pipe: only its last state, or a blank line when transient)."""
from __future__ import annotations

import time
from typing import Any

from rich.console import Console
from rich.progress import Progress, ProgressColumn, TaskID


def _clock(seconds: float) -> str:
    seconds = int(round(seconds))
    return f"{seconds // 60}:{seconds % 60:02d}"


class LineProgress:
    """The part of rich's `Progress` the package uses (`add_task`, `advance`, `update`, `console`, a context manager),
    written as lines with elapsed and remaining time: at a new tenth of a task done (at most one a `min_s` seconds,
    and the last), and at least every `every_s` seconds."""

    def __init__(self, console: Console, every_s: float = 30.0, min_s: float = 5.0) -> None:
        self.console, self.every_s, self.min_s = console, every_s, min_s
        self._tasks: dict[TaskID, dict[str, Any]] = {}

    def __enter__(self) -> LineProgress:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def add_task(self, description: str, total: float | None = None, **_: Any) -> TaskID:
        task_id = TaskID(len(self._tasks))
        self._tasks[task_id] = {"description": description, "total": total or 0, "done": 0.0,
                                "start": time.monotonic(), "said": time.monotonic(), "tenth": 0}
        return task_id

    def update(self, task_id: TaskID, completed: float | None = None, description: str | None = None,
               **_: Any) -> None:
        task = self._tasks[task_id]
        if description is not None:
            task["description"] = description
        if completed is not None:
            self.advance(task_id, completed - task["done"])

    def advance(self, task_id: TaskID, advance: float = 1) -> None:
        task = self._tasks[task_id]
        task["done"] += advance
        now, total = time.monotonic(), task["total"]
        tenth = int(10 * task["done"] / total) if total else 0
        quiet = now - task["said"]
        finished = bool(total) and task["done"] >= total
        if (tenth > task["tenth"] and (quiet >= self.min_s or finished)) or quiet >= self.every_s:
            task["tenth"], task["said"] = max(tenth, task["tenth"]), now
            self.console.print(self.line(task, now), highlight=False, soft_wrap=True)

    @staticmethod
    def line(task: dict[str, Any], now: float) -> str:
        done, total, elapsed = task["done"], task["total"], now - task["start"]
        if not total:
            return f"{task['description']}: {done:,.0f} done, {_clock(elapsed)} elapsed"
        left = elapsed * (total - done) / done if done else 0.0
        return (f"{task['description']}: {100 * min(done / total, 1.0):3.0f}% ({done:,.0f}/{total:,.0f}), "
                f"{_clock(elapsed)} elapsed, ~{_clock(left)} left")


def progress_display(console: Console, *columns: str | ProgressColumn, transient: bool = False,
                     disable: bool = False) -> Progress | LineProgress:
    """A live bar with `columns` on a terminal, else `LineProgress` lines (no output at all when `disable`)."""
    if disable or console.is_terminal:
        return Progress(*columns, console=console, transient=transient, disable=disable)
    return LineProgress(console)
