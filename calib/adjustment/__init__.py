"""The bundle adjustment: the problem (parameters, residuals), its kernel and Jacobian, the reduced normal equations, the solver, and mrcal as the peer."""
