"""raytrace.scene.model."""
