"""The report's figures (positioning.report.figures)."""

from __future__ import annotations

import numpy as np
from pos_synth import write_dataset

from positioning.io.dataset import load_dataset
from positioning.report import figures
from positioning.report.files import save_figure
from positioning.report.runs import evaluate


def test_topview_draws_every_footprint_as_one_collection_per_panel(tmp_path, monkeypatch):
    """Each panel holds the obstacles' footprints as one artist (a patch each was a third of
    the figure's time), with every polygon's vertices, and the file is written."""
    from matplotlib.collections import PatchCollection

    extra = {"obstacles_2d": [
        {"name": "a", "polygon": [[10, 10], [14, 10], [14, 12], [10, 12]]},
        {"name": "b", "polygon": [[2, 3], [4, 3], [3, 5]]},
        {"name": "bad", "polygon": [[1, 1]]},  # malformed: decoration, skipped
    ]}  # fmt: skip
    pts = np.array([[5.0, 5.0, 1.0], [20.0, 15.0, 1.0]])
    ds = load_dataset(write_dataset(tmp_path / "ds", points=pts, n_epochs=3, extra_meta=extra))
    res = evaluate(ds, ["ls", "irls"])
    seen = []
    monkeypatch.setattr(figures, "save_figure", lambda fig, path: seen.append(fig))
    figures.plot_topview(res, ["ls", "irls"], tmp_path / "tv.png")
    (fig,) = seen
    panels = [ax for ax in fig.axes if ax.get_visible() and ax.get_title()]
    assert len(panels) == 2
    for ax in panels:
        (coll,) = [c for c in ax.collections if isinstance(c, PatchCollection)]
        verts = [p.vertices[:-1] for p in coll.get_paths()]
        assert len(verts) == 2
        np.testing.assert_array_equal(verts[0], [[10, 10], [14, 10], [14, 12], [10, 12]])
        np.testing.assert_array_equal(verts[1], [[2, 3], [4, 3], [3, 5]])
        np.testing.assert_allclose(coll.get_facecolor()[0][:3], [0.85] * 3)
    save_figure(fig, tmp_path / "tv.png")
    assert (tmp_path / "tv.png").stat().st_size > 0
