"""The `fbcpr` command line (installed as the package `fbcpr.cli`)."""
