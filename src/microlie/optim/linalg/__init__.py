"""The linear algebra of the solvers: orderings, symbolic analysis, sparse Cholesky, Schur
complements and the backends."""
