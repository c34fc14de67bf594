"""raytrace.solver."""
