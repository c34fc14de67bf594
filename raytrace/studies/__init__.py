"""raytrace.studies."""
