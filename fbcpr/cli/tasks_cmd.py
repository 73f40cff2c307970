"""`fbcpr tasks`: the names a prompt accepts, straight from the registries (reward tasks by category, goal poses)."""
from __future__ import annotations

import typer
from rich.table import Table

from fbcpr.cli.common import cli_errors, console


@cli_errors
def tasks_command() -> None:
    """List the reward tasks (by category), the reward families and the goal poses that prompts accept."""
    from humanoid_env.tasks import CATEGORIES, GOALS, list_families

    table = Table(title="reward tasks (--reward; combine with * for a product, + for a mean)")
    table.add_column("category")
    table.add_column("tasks")
    by_category: dict[str, list[str]] = {}
    for task, category in CATEGORIES.items():
        by_category.setdefault(category, []).append(task)
    for category, tasks in by_category.items():
        table.add_row(category, ", ".join(tasks))
    console.print(table)
    console.print(f"reward families (any parameters): {', '.join(list_families())}", highlight=False)
    console.print(f"goal poses (--goal): {', '.join(GOALS)}", highlight=False)


def register(app: typer.Typer) -> None:
    app.command("tasks")(tasks_command)
