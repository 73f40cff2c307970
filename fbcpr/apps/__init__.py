"""Applications built on a trained BFM (NPMP distillation and reuse)."""
