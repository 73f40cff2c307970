"""Typer app behind the `fbcpr` console script. Each command group lives in its own module."""
from __future__ import annotations

import typer

app = typer.Typer(help="FB-CPR behavioral foundation model for the SMPL humanoid.", no_args_is_help=True)


def main() -> None:
    """Console-script entry point."""
    app()


if __name__ == "__main__":
    main()
