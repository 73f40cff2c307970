"""`python -m fbcpr ...`: the `fbcpr` CLI, for launchers that start a module (`torchrun -m fbcpr train ...`)."""
from fbcpr.cli.app import main

if __name__ == "__main__":
    main()
