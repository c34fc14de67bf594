"""raytrace.viz."""
