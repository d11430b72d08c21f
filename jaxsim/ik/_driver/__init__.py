"""The IK driver: the public entry points, input checks, the kernel choice, implicit derivatives and tracking."""
