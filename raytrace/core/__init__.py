"""raytrace.core."""
