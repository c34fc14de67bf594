"""raytrace.physics."""
