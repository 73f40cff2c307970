"""Run configs shipped with fbcpr, installed as the data package `fbcpr.configs` so `fbcpr demo` finds its default."""
