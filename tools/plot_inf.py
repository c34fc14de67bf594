#!/usr/bin/env python
"""Figures of docs/inf.md: top views of the four InF profiles and their LoS check.

    python tools/plot_inf.py                      # docs/inf_halls.png and docs/inf_los_check.png
    python tools/plot_inf.py --seeds 5 --size 120x60x10

The LoS panels pool ``--seeds`` halls per profile (200 points each) and show the generated LoS
fraction per distance bin (95 % Wilson intervals) against the TR 38.901 curve exp(-d/k).
"""

from __future__ import annotations

import argparse
import io
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from raytrace.cli.harness import OneLineParser, run_tool
from raytrace.core.errors import HallrayError
from raytrace.core.fileio import write_atomic
from raytrace.halls.inf import (
    PROFILES,
    generate_hall,
    los_check,
    parse_size,
    split_spec,
)
from raytrace.halls.spec import parse_hall_spec
from raytrace.viz.topview import plot_top_view

ROOT = Path(__file__).resolve().parent.parent


def _save(fig, path: Path) -> None:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", bbox_inches="tight", dpi=110)
    plt.close(fig)
    write_atomic(path, buf.getvalue())
    print(f"wrote {path}")


def halls_figure(size: str, seed: int, path: Path) -> None:
    fig, axes = plt.subplots(2, 2, figsize=(11, 11))
    for ax, profile in zip(axes.ravel(), PROFILES):
        spec = generate_hall(profile, size, seed, n_points=20, los_notes=False)
        hall = parse_hall_spec(split_spec(spec)[0])
        plot_top_view(ax, hall, show_legend=profile == "InF-DL")
        info = spec["_inf"]
        p = info["params"]
        ax.set_title(
            f"{profile} seed {seed}: r = {info['achieved_density']:.2f}, "
            f"d = {p['clutter_size']:g} m, h_c = {p['clutter_height']:g} m, "
            f"h_BS = {p['bs_height']:g} m",
            fontsize=9,
        )
    _save(fig, path)


def los_figure(size: str, seeds: int, path: Path) -> None:
    fig, axes = plt.subplots(2, 2, figsize=(11, 7.5))
    for ax, profile in zip(axes.ravel(), PROFILES):
        sample = los_check(profile, seeds, size, n_points=200)
        dense = PROFILES[profile][0]
        width = 2.0 if dense else 5.0
        bins = sample.bins(width)
        mid = np.array([0.5 * (b["d_lo_m"] + b["d_hi_m"]) for b in bins])
        frac = np.array([b["los_fraction"] for b in bins])
        err = np.clip(
            np.array(
                [[b["los_fraction"] - b["ci_lo"], b["ci_hi"] - b["los_fraction"]] for b in bins]
            ),
            0.0,
            None,
        ).T
        ax.errorbar(mid, frac, yerr=err, fmt="o", ms=3.5, capsize=2, label="generated halls")
        top = 30.0 if dense else bins[-1]["d_hi_m"]
        d = np.linspace(0.0, top, 300)
        k3, kf = sample.k_3gpp_m, sample.fit_k_m()
        ax.plot(d, np.exp(-d / k3), "k-", label=f"TR 38.901, k = {k3:.1f} m")
        ax.plot(d, np.exp(-d / kf), "C1--", label=f"fit, k = {kf:.1f} m")
        ax.set_xlim(0, top)
        ax.set_ylim(-0.02, 1.02)
        ax.set_title(
            f"{profile}: {sample.n_links} links in {sample.n_halls} halls, LoS "
            f"{sample.los_fraction:.3f} (3GPP {sample.los_fraction_3gpp:.3f})",
            fontsize=9,
        )
        ax.set_xlabel("d_2D (m)")
        ax.set_ylabel("P(LoS)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    _save(fig, path)


def parser() -> argparse.ArgumentParser:
    ap = OneLineParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="120x60x10", help="hall of the LoS check [120x60x10]")
    ap.add_argument("--halls-size", default="42x46x8.8", help="hall of the top views [42x46x8.8]")
    ap.add_argument("--seeds", type=int, default=5, help="halls per profile in the LoS check [5]")
    ap.add_argument("--out", default=str(ROOT / "docs"), help="folder of the two PNGs [docs/]")
    return ap


def _main(args: argparse.Namespace) -> int:
    for name, size in (("--size", args.size), ("--halls-size", args.halls_size)):
        try:  # a bad size or number of seeds before any work: one line
            parse_size(size)
        except HallrayError as exc:
            raise HallrayError(f"{name}: {exc}") from None
    if args.seeds < 1:
        raise HallrayError(f"--seeds must be >= 1, got {args.seeds}")
    out = Path(args.out)
    if not out.is_dir():
        raise HallrayError(f"--out {out} is not an existing directory")
    halls_figure(args.halls_size, 0, out / "inf_halls.png")
    los_figure(args.size, args.seeds, out / "inf_los_check.png")
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_tool(_main, parser(), argv)


if __name__ == "__main__":
    raise SystemExit(main())
