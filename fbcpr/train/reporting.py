"""How a training run reports: the rich progress bar's columns and the TensorBoard writer (optional)."""
from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

from rich.progress import BarColumn, ProgressColumn, Task, TextColumn, TimeElapsedColumn, TimeRemainingColumn
from rich.table import Column
from rich.text import Text


def progress_columns() -> list[ProgressColumn]:
    """Training bar columns: steps, rate, elapsed and ETA keep their width; the metrics (a `metrics` task field)
    take what is left and are cut first, so the bar stays readable at 80 columns."""
    def fixed() -> Column:
        return Column(no_wrap=True)

    return [BarColumn(bar_width=10), TextColumn("{task.completed:,}/{task.total:,}", table_column=fixed()),
            RateColumn(table_column=fixed()), TimeElapsedColumn(table_column=fixed()),
            TextColumn("eta", table_column=fixed()), TimeRemainingColumn(table_column=fixed()),
            TextColumn("{task.fields[metrics]}", table_column=Column(no_wrap=True, overflow="ellipsis", ratio=1))]


class RateColumn(ProgressColumn):
    """Env steps per second."""

    def render(self, task: Task) -> Text:
        return Text(f"{task.speed:,.0f}/s" if task.speed else "-/s")


def summary_writer(path: Path) -> Any:
    """A TensorBoard writer, or None where tensorboard is not installed (metrics.csv is then the only log)."""
    try:
        from torch.utils.tensorboard import SummaryWriter
    except ImportError:
        warnings.warn("tensorboard is not installed: metrics go to metrics.csv only", RuntimeWarning, stacklevel=2)
        return None
    return SummaryWriter(str(path))


