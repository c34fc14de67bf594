"""Command-line tools for synthetic InF halls: ``make-hall`` and ``hall-los-check``.

Both turn bad input into one line ``error: ...`` on stderr and exit status 2; outputs are written
atomically (no half-written file).
"""

from __future__ import annotations

import argparse
import io
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from ..core.errors import HallrayError
from .harness import OneLineParser, run_tool

#: Files that ``make-hall -o DIR`` writes.
HALL_YAML = "hall.yaml"
HALL_GLB = "hall.glb"
INF_JSON = "inf.json"


def _bs_grid(text: str) -> tuple[int, int]:
    parts = text.lower().split("x")
    try:
        vals = [int(p) for p in parts]
    except ValueError:
        vals = []
    if len(vals) != 2 or min(vals) < 1:
        raise argparse.ArgumentTypeError(f"expected NXxNY (e.g. 2x2), got {text!r}")
    return (vals[0], vals[1])


def _add_generator_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--size", help="hall interior LxWxH in m, e.g. 42x46x8.8 [120x60x10]")
    p.add_argument("--density", type=float, help="clutter density r [0.2 sparse, 0.6 dense]")
    p.add_argument("--clutter-size", type=float, help="d_clutter, m [10 sparse, 2 dense]")
    p.add_argument("--clutter-height", type=float, help="h_c, m [2 sparse, 6 dense]")
    p.add_argument("--height-spread", type=float, default=0.0, help="box heights h_c*(1 +- s) [0]")
    p.add_argument("--bs-height", type=float, help="h_BS, m [1.5 low, 8 high]")
    p.add_argument("--bs-spacing", type=float, default=20.0, help="BS grid spacing, m [20]")
    p.add_argument("--bs-grid", type=_bs_grid, metavar="NXxNY", help="BS grid (overrides spacing)")


def _generator_kwargs(args: argparse.Namespace) -> dict[str, Any]:
    return {
        "density": args.density,
        "clutter_size": args.clutter_size,
        "clutter_height": args.clutter_height,
        "height_spread": args.height_spread,
        "bs_height": args.bs_height,
        "bs_spacing": args.bs_spacing,
        "bs_grid": args.bs_grid,
    }


# -- make-hall --------------------------------------------------------------------------------
def make_hall_parser() -> argparse.ArgumentParser:
    p = OneLineParser(
        prog="make-hall",
        description=(
            "Generate a synthetic indoor-factory hall after 3GPP TR 38.901 InF: clutter boxes of "
            "the profile's density, size and height, base stations on a grid, test points at "
            "1.5 m on the free floor. Writes DIR/hall.yaml (the hall schema of docs/hall.md), "
            "DIR/hall.glb and DIR/inf.json (the parameters)."
        ),
    )
    p.add_argument("--profile", required=True, help="InF-SL, InF-DL, InF-SH or InF-DH")
    p.add_argument("--seed", type=int, default=0, help="random seed (same seed, same bytes) [0]")
    p.add_argument("--points", type=int, default=50, help="number of test points [50]")
    _add_generator_options(p)
    p.add_argument("-o", "--output", required=True, metavar="DIR", help="output directory")
    return p


def make_hall_main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``make-hall``: 0 on success, 2 on bad input."""
    return run_tool(_make_hall, make_hall_parser(), argv)


def _make_hall(args: argparse.Namespace) -> int:
    from hallray.safe_output import output_dir

    # the three files appear together or not at all; a previous make-hall output is replaced,
    # any other non-empty directory (or one with files make-hall did not write) refused
    with output_dir(args.output, command="make-hall", replace_previous=True) as tmp:
        written = make_hall(
            args.profile, args.size, args.seed, tmp, n_points=args.points,
            **_generator_kwargs(args),
        )  # fmt: skip
    written["dir"] = args.output
    info = written["info"]
    p = info["params"]
    print(
        f"wrote {written['dir']}: {HALL_YAML}, {HALL_GLB}, {INF_JSON}: {p['profile']} "
        f"{'x'.join(f'{v:g}' for v in p['size'])} m, seed {p['seed']}, {info['n_clutter']} clutter "
        f"boxes (r = {info['achieved_density']:.3f}), "
        f"{p['bs_grid'][0] * p['bs_grid'][1]} base stations at {p['bs_height']:g} m, "
        f"{p['n_points']} points; 3GPP k = {info['k_subsce_m']:.2f} m"
    )
    return 0


def make_hall(
    profile: str,
    size: str | Sequence[float] | None,
    seed: int,
    out_dir: str | Path,
    **kwargs: Any,
) -> dict[str, Any]:
    """Generate a hall and write ``hall.yaml``, ``hall.glb`` and ``inf.json`` into ``out_dir``
    (created if its parent exists). Everything is generated and validated before the first file
    is written; each file is written atomically. Returns ``{"dir", "spec", "info"}``."""
    from ..core.fileio import write_atomic
    from ..halls.inf.generator import generate_hall, hall_yaml, split_spec
    from ..halls.spec.build import build_scene, glb_bytes
    from ..halls.spec.parse import parse_hall_spec

    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise HallrayError(f"output {out} exists and is not a directory")
    if not out.exists() and not out.parent.is_dir():
        raise HallrayError(f"cannot create {out}: directory {out.parent} does not exist")
    spec = generate_hall(profile, size, seed, **kwargs)
    hall, info = split_spec(spec)
    text = hall_yaml(spec)
    glb = glb_bytes(build_scene(parse_hall_spec(hall)))
    meta = json.dumps(info, indent=1, sort_keys=True) + "\n"
    out.mkdir(exist_ok=True)
    write_atomic(out / HALL_YAML, text.encode("utf-8"))
    write_atomic(out / HALL_GLB, glb)
    write_atomic(out / INF_JSON, meta.encode("utf-8"))
    return {"dir": str(out), "spec": hall, "info": info}


# -- hall-los-check ---------------------------------------------------------------------------
def hall_los_check_parser() -> argparse.ArgumentParser:
    p = OneLineParser(
        prog="hall-los-check",
        description=(
            "Compare the line-of-sight fraction of generated InF halls (Embree segment tests "
            "from every base station to every point) with the 3GPP TR 38.901 InF LoS "
            "probability exp(-d_2D / k), per distance bin. TARGET is a directory written by "
            "make-hall, or a profile: then --seeds halls are generated and pooled."
        ),
    )
    p.add_argument("target", help="make-hall output directory, or InF-SL|InF-DL|InF-SH|InF-DH")
    p.add_argument("--seeds", type=int, help="number of halls for a profile (seeds 0..N-1) [5]")
    p.add_argument("--first-seed", type=int, default=0, help="first seed for a profile [0]")
    p.add_argument("--points", type=int, default=200, help="points per generated hall [200]")
    _add_generator_options(p)
    p.add_argument("--bin", type=float, help="distance bin width, m [max(2, d_clutter / 2)]")
    p.add_argument("-o", "--plot", metavar="PNG", help="write the comparison as a PNG")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    return p


def hall_los_check_main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``hall-los-check``: 0 on success, 2 on bad input."""
    return run_tool(_hall_los_check, hall_los_check_parser(), argv)


def _hall_los_check(args: argparse.Namespace) -> int:
    if args.points is not None and args.points < 1:
        raise HallrayError(f"--points must be >= 1, got {args.points}")
    if args.plot:  # before any work
        from hallray.safe_output import check_output

        if not str(args.plot).lower().endswith(".png"):
            raise HallrayError(f"--plot {args.plot}: must end in .png")
        target = args.target if Path(args.target).is_dir() else None
        check_output(args.plot, inputs=[target], what="--plot")
    sample, params = _los_sample(args)
    if sample.n_links == 0:
        raise HallrayError("no base station -> point links to check: give more --points")
    width = args.bin if args.bin is not None else max(2.0, params["clutter_size"] / 2.0)
    if not (math.isfinite(width) and width > 0):
        raise HallrayError(f"--bin must be a positive number of metres, got {args.bin!r}")
    summary = sample.summary(width)
    summary["params"] = params
    if args.plot:
        _plot(sample, summary, args.plot)
    if args.json:
        print(json.dumps(_jsonable(summary), indent=1))
    else:
        print(format_los_report(summary))
        if args.plot:
            print(f"\nplot written to {args.plot}")
    return 0


def _jsonable(x: Any) -> Any:
    if isinstance(x, float) and not math.isfinite(x):
        return None if math.isnan(x) else ("inf" if x > 0 else "-inf")
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    return x


def _los_sample(args: argparse.Namespace) -> tuple[Any, dict[str, Any]]:
    from ..halls.inf.los import los_check, los_sample
    from ..halls.inf.params import PROFILES, canonical_profile, resolve_params
    from ..halls.spec.parse import load_hall_spec
    from ..scene.io import load_scene

    target = Path(args.target)
    if target.is_dir():
        if args.seeds is not None:
            raise HallrayError("--seeds applies to a profile, not to a hall directory")
        info_path = target / INF_JSON
        glb_path = target / HALL_GLB
        for path in (info_path, glb_path, target / HALL_YAML):
            if not path.is_file():
                raise HallrayError(f"{path} not found (write the hall with make-hall -o {target})")
        try:
            from hallray import strict_json

            info = strict_json.loads(info_path.read_text(encoding="utf-8"))
            params = dict(info["params"])
            k = float(info["k_subsce_m"])
        except (ValueError, KeyError, TypeError) as exc:
            raise HallrayError(f"{info_path}: not a make-hall parameter file ({exc})") from None
        hall = load_hall_spec(target / HALL_YAML)
        scene = load_scene(glb_path)
        sample = los_sample(scene, hall, k, label=f"{params.get('profile', '?')} ({target})")
        params["n_halls"] = 1
        return sample, params
    if target.exists():
        raise HallrayError(f"{target} is not a directory")
    if args.target.strip().lower() not in {p.lower() for p in PROFILES}:
        raise HallrayError(
            f"{args.target!r} is neither a make-hall directory nor a profile "
            f"({', '.join(PROFILES)})"
        )
    n = 5 if args.seeds is None else args.seeds
    if n < 1:
        raise HallrayError(f"--seeds must be >= 1, got {n}")
    from hallray.limits import check_size

    check_size("seeds", n, f"--seeds {n}")
    if args.first_seed < 0:
        raise HallrayError(f"--first-seed must be >= 0, got {args.first_seed}")
    kwargs = _generator_kwargs(args)
    params = resolve_params(args.target, args.size, args.first_seed, n_points=args.points, **kwargs)
    links = float(n) * params.n_points * params.bs_grid[0] * params.bs_grid[1]
    check_size("los links", links, f"--seeds {n} x {params.n_points} points x "
               f"{params.bs_grid[0] * params.bs_grid[1]} base stations")  # fmt: skip
    sample = los_check(
        args.target,
        range(args.first_seed, args.first_seed + n),
        args.size,
        n_points=args.points,
        **kwargs,
    )
    out = params.to_dict()
    out["seed"] = list(range(args.first_seed, args.first_seed + n))
    out["n_halls"] = n
    out["profile"] = canonical_profile(args.target)
    return sample, out


def format_los_report(summary: dict[str, Any]) -> str:
    """The text report of ``hall-los-check``."""
    p = summary["params"]
    size = "x".join(f"{v:g}" for v in p["size"])
    n_bs = p["bs_grid"][0] * p["bs_grid"][1]
    k3, kf = summary["k_3gpp_m"], summary["k_fit_m"]
    ratio = kf / k3 if math.isfinite(k3) and math.isfinite(kf) and k3 > 0 else math.nan
    if math.isfinite(kf) and kf > 0:
        fitted = f"{kf:.2f} m (ratio to 3GPP {ratio:.2f})"
    else:  # every link LoS (k = inf) or none (k = 0): exp(-d/k) has nothing to fit
        which = "every" if kf == math.inf else "no"
        fitted = f"not defined: {which} link is LoS (use more points or seeds)"
    lines = [
        f"{p['profile']}: {summary['n_halls']} hall(s) {size} m, {n_bs} BS x {p['n_points']} "
        f"points, {summary['n_links']} links",
        f"3GPP TR 38.901: r = {p['density']:g}, d_clutter = {p['clutter_size']:g} m, "
        f"h_c = {p['clutter_height']:g} m, h_BS = {p['bs_height']:g} m, "
        f"h_UT = {p['ut_height']:g} m -> k = {k3:.2f} m",
        f"fitted k (max. likelihood of exp(-d/k)) = {fitted}",
        f"LoS fraction: generated {summary['los_fraction']:.3f}, "
        f"3GPP for the same distances {summary['los_fraction_3gpp']:.3f}",
        "",
        f"{'d_2D (m)':>13} {'links':>6} {'LoS':>6}  {'generated [95% CI]':<22} {'3GPP':>6}",
    ]
    for b in summary["bins"]:
        lines.append(
            f"{b['d_lo_m']:6.1f}-{b['d_hi_m']:6.1f} {b['n']:6d} {b['n_los']:6d}  "
            f"{b['los_fraction']:.3f} [{b['ci_lo']:.3f}, {b['ci_hi']:.3f}]   {b['p_los_3gpp']:6.3f}"
        )
    return "\n".join(lines)


def _plot(sample: Any, summary: dict[str, Any], path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from ..core.fileio import write_atomic
    from ..halls.inf.params import los_probability_3gpp

    if not str(path).lower().endswith(".png"):
        raise HallrayError(f"--plot {path}: must end in .png")
    bins = summary["bins"]
    fig, ax = plt.subplots(figsize=(6.4, 4.0), dpi=120)
    if bins:
        mid = np.array([0.5 * (b["d_lo_m"] + b["d_hi_m"]) for b in bins])
        frac = np.array([b["los_fraction"] for b in bins])
        err = np.array(
            [[b["los_fraction"] - b["ci_lo"], b["ci_hi"] - b["los_fraction"]] for b in bins]
        )
        err = np.clip(err, 0.0, None).T
        ax.errorbar(mid, frac, yerr=err, fmt="o", ms=4, capsize=2, label="generated halls (95% CI)")
        d = np.linspace(0.0, bins[-1]["d_hi_m"], 300)
        k3, kf = summary["k_3gpp_m"], summary["k_fit_m"]
        ax.plot(d, los_probability_3gpp(d, k3), "k-", label=f"3GPP exp(-d/k), k = {k3:.1f} m")
        if math.isfinite(kf) and kf > 0:
            ax.plot(d, np.exp(-d / kf), "C1--", label=f"fit exp(-d/k), k = {kf:.1f} m")
    p = summary["params"]
    ax.set_title(
        f"{p['profile']}: LoS probability, {summary['n_links']} links, {summary['n_halls']} hall(s)"
    )
    ax.set_xlabel("horizontal distance d_2D (m)")
    ax.set_ylabel("P(LoS)")
    ax.set_ylim(-0.02, 1.02)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", bbox_inches="tight")
    plt.close(fig)
    out = Path(path)
    write_atomic(out, buf.getvalue())
