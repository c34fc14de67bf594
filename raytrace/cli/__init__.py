"""raytrace.cli.trace_scene."""
