"""Benchmark of zero-shot tasks (App. C.3): metrics, agents, the episode runner and reports."""
