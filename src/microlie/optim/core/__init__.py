"""The estimator's core: variables, factors, noise models, robust losses, the graph, its
least-squares problem and the solvers."""
