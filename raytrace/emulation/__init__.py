"""raytrace.emulation."""
