"""raytrace.halls."""
