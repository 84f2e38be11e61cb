"""Factor graphs and least-squares solvers."""
