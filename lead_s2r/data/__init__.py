"""Training data: sample -> tensor transforms, per-source loaders, the sim/real mixing schedule."""
