"""The implicit step: the problem, Newton (direction, line search, stop test), the Hessian, PCG, contact, the implicit derivative."""
