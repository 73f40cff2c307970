"""Building blocks every method shares: networks, the observation normaliser, ensemble TD, optimiser state, precision,
CUDA graphs, latent maths and the hooks that keep data-parallel replicas equal."""
