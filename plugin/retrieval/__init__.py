"""Finding and fitting examples: shape context and DTW, MVC warps, example databases."""
