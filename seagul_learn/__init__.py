"""seagul_learn: trajectory optimization with dual gradients, SEAGuL sampling, value networks, training, CLI."""
