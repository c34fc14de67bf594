"""Bundled scene data (installed as raytrace._scenes)."""
