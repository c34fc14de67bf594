"""raytrace.viz: pictures (:mod:`.render`), glTF export (:mod:`.export`), heatmaps
(:mod:`.heatmap`) and the interactive 3D view (:mod:`.interactive`: :func:`preview`)."""

from .interactive import preview, view_html

__all__ = ["preview", "view_html"]
