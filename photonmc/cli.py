"""Command line: argument parsing only; the work happens in loop.py."""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from .errors import PhotonmcError
from .methods import PLANNED


def _define(text: str):
    if "=" not in text:
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE, got '{text}'")
    name, value = text.split("=", 1)
    return name, value


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="photonmc", description="Photon-mapping renderer with MCMC-guided photons.")
    sub = p.add_subparsers(dest="command", required=True)
    r = sub.add_parser("render", help="render a scene to EXR + PNG")
    _add_render_options(r, default_out="render.exr")
    r.add_argument("--stats", metavar="PATH.json", help="write render statistics as JSON")
    r.add_argument("--checkpoint", type=float, default=60.0, metavar="SECONDS",
                   help="also write the image every SECONDS while rendering (0: only at the end; default 60)")
    r.add_argument("--quiet", action="store_true", help="no progress output")
    v = sub.add_parser("preview", help="watch a render refine in a window (keys: s save, +/- exposure, "
                                       "space pause, q quit and save)")
    _add_render_options(v, default_out="preview.exr", budget_help=" (default: until you quit)")
    v.add_argument("--frames", metavar="DIR", help="no window: write each frame the window would show "
                                                   "to DIR/frame-NNNNN.png (needs --time or --iterations)")
    c = sub.add_parser("converge", help="measure error against time for several methods")
    c.add_argument("scene", help="Mitsuba 3 XML scene")
    c.add_argument("--methods", required=True, help="comma-separated, e.g. pt,sppm")
    c.add_argument("--reference", required=True, help="reference EXR at the scene's resolution")
    cb = c.add_mutually_exclusive_group(required=True)
    cb.add_argument("--time", type=float, help="render seconds per method (compilation excluded)")
    cb.add_argument("--iterations", type=int, help="iterations per method")
    c.add_argument("--out", default="converge-out", help="output directory (CSV, plot, table, images)")
    c.add_argument("--seed", type=int, default=0)
    c.add_argument("--threads", type=int)
    c.add_argument("--max-depth", type=int)
    c.add_argument("--photons", type=int)
    c.add_argument("--alpha", type=float)
    c.add_argument("--radius", type=float)
    _add_guiding_options(c)
    _add_vcm_options(c)
    c.add_argument("-D", dest="defines", action="append", type=_define, default=[], metavar="NAME=VALUE")
    return p


def _add_render_options(r, default_out: str, budget_help: str = ""):
    """Options shared by `render` and `preview`: the same render, shown differently."""
    r.add_argument("scene", nargs="?", help="Mitsuba 3 XML scene (default: the bundled Cornell box)")
    r.add_argument("--method", default="pt", help=f"one of {', '.join(PLANNED)} (default pt)")
    budget = r.add_mutually_exclusive_group()
    budget.add_argument("--time", type=float, help="wall-clock budget in seconds" + budget_help)
    budget.add_argument("--iterations", type=int, help="number of progressive iterations" + budget_help)
    r.add_argument("--out", default=default_out, help=f"output .exr (also writes .png) or .png (default {default_out})")
    r.add_argument("--seed", type=int, default=0)
    r.add_argument("--arch", default="cpu", choices=["cpu", "cuda", "vulkan"])
    r.add_argument("--threads", type=int, help="CPU threads (default: all cores)")
    r.add_argument("--max-depth", type=int, help="override the scene's max_depth (Mitsuba meaning)")
    pm = r.add_argument_group("photon mapping (sppm, visibility, spatial-tf)")
    pm.add_argument("--photons", type=int, help="photon paths per iteration (default: one per pixel)")
    pm.add_argument("--alpha", type=float, help="fraction of new photons kept by the radius update (default 2/3)")
    pm.add_argument("--radius", type=float, help="initial gather radius in scene units "
                                                 "(default: 2 pixel footprints at each pixel's first hit)")
    _add_guiding_options(r)
    _add_vcm_options(r)
    r.add_argument("-D", dest="defines", action="append", type=_define, default=[], metavar="NAME=VALUE",
                   help="set a scene parameter ($NAME), overriding its <default>")


def _add_guiding_options(parser):
    g = parser.add_argument_group("Markov-chain photon guiding (visibility, spatial-tf)")
    g.add_argument("--chains", type=int, help="parallel Markov-chain ladders (default 4)")
    g.add_argument("--target-acceptance", type=float,
                   help="acceptance rate the mutation size adapts to (default 0.234)")
    g.add_argument("--proposal-failures", choices=["keep", "drop"],
                   help="keep (default): a rejected proposal repeats the current state, as Metropolis-Hastings "
                        "requires; drop: the remedy of Zeng & Wei 2019, which is biased (docs/guiding.md)")
    g.add_argument("--expected-values", action="store_true", default=None,
                   help="splat proposals with their acceptance probability (Rao-Blackwellised)")
    g.add_argument("--path-target", choices=["max", "sum"],
                   help="spatial-tf: a path's target is the max (default) or sum of the importance of the points it hits")


def _add_vcm_options(parser):
    g = parser.add_argument_group("vertex connection and merging (vcm; --alpha and --radius as above, "
                                  "default alpha 0.75 and 2 pixel footprints at the median first-hit distance)")
    g.add_argument("--light-paths", type=int, help="light subpaths per iteration (default: one per pixel)")
    g.add_argument("--techniques", help="vcm (default: all), bpt (no merging), bpm (merging only), "
                                        "lt (light tracing only)")


def _method_options(args) -> dict:
    return {"photons": args.photons, "alpha": args.alpha, "radius": args.radius, "chains": args.chains,
            "target_acceptance": args.target_acceptance, "proposal_failures": args.proposal_failures,
            "expected_values": args.expected_values, "path_target": args.path_target,
            "light_paths": args.light_paths, "techniques": args.techniques}


def cmd_converge(args) -> int:
    from . import runtime
    from .converge import converge
    from .methods import method_class
    from .loop import Budget
    from .scene import load_scene

    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    if not methods:
        raise PhotonmcError("--methods is empty")
    for m in methods:
        method_class(m)
    if not Path(args.reference).is_file():
        raise PhotonmcError(f"reference image '{args.reference}' not found")
    budget = Budget(time=args.time, iterations=args.iterations)
    scene = load_scene(args.scene, dict(args.defines))
    runtime.init("cpu", args.threads)
    options = _method_options(args)
    _, table = converge(scene, Path(args.scene).parent.name or args.scene, methods, args.reference, budget,
                        args.out, seed=args.seed, options=options, max_depth=args.max_depth,
                        log=lambda msg: print(msg, file=sys.stderr))
    print(table)
    print(f"wrote {args.out}/convergence.csv, convergence.png, convergence.md", file=sys.stderr)
    return 0


def cmd_render(args) -> int:
    from . import imageio
    from .loop import Budget, prepare, run, safe_image

    out = imageio.check_output_path(args.out)
    if args.stats and not Path(args.stats).resolve().parent.is_dir():
        raise PhotonmcError(f"directory for --stats '{args.stats}' does not exist")
    if not (args.checkpoint >= 0):
        raise PhotonmcError(f"--checkpoint must be >= 0 seconds, got {args.checkpoint}")
    budget = Budget(time=args.time, iterations=args.iterations)
    options = _method_options(args)
    prepared = prepare(args.scene, method=args.method, seed=args.seed, max_depth=args.max_depth,
                       arch=args.arch, threads=args.threads, options=options, params=dict(args.defines))
    for w in prepared.scene.warnings:
        print(f"photonmc: warning: {w}", file=sys.stderr)
    def metadata(iterations):
        return {"method": args.method, "seed": args.seed, "iterations": iterations, "scene": prepared.scene.path}

    last_write = [time.perf_counter()]

    def checkpoint(method, iteration, elapsed):
        if args.checkpoint > 0 and time.perf_counter() - last_write[0] >= args.checkpoint:
            imageio.write_image(out, safe_image(method.image()), metadata(iteration))
            last_write[0] = time.perf_counter()

    result = run(prepared, budget, quiet=args.quiet, on_iteration=checkpoint)
    written = imageio.write_image(out, result.image, metadata(result.stats["iterations"]))
    stats = result.stats
    if stats.get("nonfinite_samples_dropped") or stats.get("nonfinite_pixels_zeroed"):
        print(f"photonmc: warning: {stats.get('nonfinite_samples_dropped', 0)} NaN/Inf samples dropped, "
              f"{stats['nonfinite_pixels_zeroed']} non-finite pixels set to 0", file=sys.stderr)
    if args.stats:
        Path(args.stats).write_text(json.dumps(stats, indent=2) + "\n")
    if not args.quiet:
        state = "interrupted after" if result.interrupted else "finished"
        print(f"photonmc: {state} {stats['iterations']} iterations in {stats['wall_seconds']['render']:.1f} s; "
              f"wrote {', '.join(str(p) for p in written)}", file=sys.stderr)
    return 130 if result.interrupted else 0


def cmd_preview(args) -> int:
    from .loop import Budget, default_scene_path
    from .methods import method_class
    from .preview import Job, preview
    from .scene import load_scene

    method_class(args.method)
    params = dict(args.defines)
    scene_path = str(args.scene or default_scene_path())
    scene = load_scene(scene_path, params)      # fail here, before a window opens, on a bad scene
    for w in scene.warnings:
        print(f"photonmc: warning: {w}", file=sys.stderr)
    budget = Budget(time=args.time, iterations=args.iterations,
                    until_stopped=args.time is None and args.iterations is None)
    job = Job(scene=scene_path, params=params, method=args.method, budget=budget, seed=args.seed,
              max_depth=args.max_depth, arch=args.arch, threads=args.threads, options=_method_options(args))
    return preview(job, args.out, frames_dir=args.frames, shape=(scene.camera.height, scene.camera.width))


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        if args.command == "render":
            return cmd_render(args)
        if args.command == "converge":
            return cmd_converge(args)
        if args.command == "preview":
            return cmd_preview(args)
    except PhotonmcError as e:
        print(f"photonmc: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("photonmc: aborted", file=sys.stderr)
        return 130
    return 1


if __name__ == "__main__":
    sys.exit(main())
