"""A toy point-mass world with demonstrations, for fast tests and learning evidence."""
