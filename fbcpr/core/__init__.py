"""The base layer: config schema, the plug-in registry, the two protocols, checkpoints on disk and the errors."""
