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


def _number_or_auto(what: str):
    """An argparse type: an integer, or the word auto (--photons, --camera-paths, --light-paths)."""
    def parse(text: str):
        if text == "auto":
            return text
        try:
            return int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a number of {what} or 'auto', got '{text}'") from None
    return parse


_photons = _number_or_auto("photons")
_camera_paths = _number_or_auto("camera paths")
_light_paths = _number_or_auto("light paths")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="photonmc", description="Photon-mapping renderer with MCMC-guided photons.")
    sub = p.add_subparsers(dest="command", required=True)
    r = sub.add_parser("render", help="render a scene to EXR + PNG, and its render state")
    _add_render_options(r, default_out=None)
    r.add_argument("--stats", metavar="PATH.json", help="write render statistics as JSON")
    r.add_argument("--checkpoint", type=float, default=60.0, metavar="SECONDS",
                   help="also write the image and the render state every SECONDS while rendering "
                        "(0: only at the end; default 60)")
    r.add_argument("--quiet", action="store_true", help="no progress output")
    r.add_argument("--resume", metavar="X.state", help="continue the render this state was saved from; "
                   "--iterations/--time count the whole render (default --out: X.exr)")
    m = sub.add_parser("merge", help="merge render states of one scene rendered with different seeds")
    m.add_argument("states", nargs="+", metavar="STATE", help="render states (.state) to merge")
    m.add_argument("--out", required=True, help="merged .exr (also .png, and the merged .state beside it)")
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
    cs = c.add_mutually_exclusive_group()
    cs.add_argument("--seed", type=int, default=0)
    cs.add_argument("--seeds", type=_seed_list, help="comma-separated seeds, e.g. 0,1,2,3: one render per method "
                                                     "and seed, figures as mean and spread over seeds")
    c.add_argument("--interleave", action="store_true",
                   help="render the methods together in alternating rounds (each still gets its budget), so "
                        "that a machine whose speed drifts drifts for all alike; all stay in memory together")
    c.add_argument("--threads", type=int)
    c.add_argument("--max-depth", type=int)
    c.add_argument("--pixel-samples", choices=["sobol", "independent"],
                   help="where in its pixel each camera path starts: sobol (default), the pixel's Owen-scrambled Sobol' "
                        "sequences over the render (edges and slits seen by the camera converge faster), or independent "
                        "random positions (docs/convergence.md, 'Stratified pixel positions')")
    c.add_argument("--photons", type=_photons, help="photon paths per iteration, or auto")
    c.add_argument("--camera-paths", type=_camera_paths, help="camera paths per pixel per pass, or auto")
    c.add_argument("--alpha", type=float)
    c.add_argument("--radius", type=float)
    c.add_argument("--radius-rule", choices=["progressive", "balanced"])
    c.add_argument("--disc", choices=["full", "clipped", "linear", "sealed"])
    _add_guiding_options(c)
    _add_vcm_options(c)
    c.add_argument("-D", dest="defines", action="append", type=_define, default=[], metavar="NAME=VALUE")
    return p


def _add_render_options(r, default_out: str, budget_help: str = ""):
    """Options shared by `render` and `preview`: the same render, shown differently."""
    r.add_argument("scene", nargs="?", help="Mitsuba 3 XML scene (default: the bundled Cornell box)")
    r.add_argument("--method", help=f"one of {', '.join(PLANNED)} (default pt)")
    budget = r.add_mutually_exclusive_group()
    budget.add_argument("--time", type=float, help="wall-clock budget in seconds" + budget_help)
    budget.add_argument("--iterations", type=int, help="number of progressive iterations" + budget_help)
    r.add_argument("--out", default=default_out, help="output .exr (also writes .png) or .png "
                   f"(default {default_out or 'render.exr'})")
    r.add_argument("--seed", type=int, help="random seed (default 0)")
    r.add_argument("--arch", default="cpu", choices=["cpu", "cuda", "vulkan"])
    r.add_argument("--threads", type=int, help="CPU threads (default: all cores)")
    r.add_argument("--max-depth", type=int, help="override the scene's max_depth (Mitsuba meaning)")
    r.add_argument("--pixel-samples", choices=["sobol", "independent"],
                   help="where in its pixel each camera path starts: sobol (default), the pixel's Owen-scrambled Sobol' "
                        "sequences over the render (edges and slits seen by the camera converge faster), or independent "
                        "random positions (docs/convergence.md, 'Stratified pixel positions')")
    pm = r.add_argument_group("photon mapping (sppm, visibility, spatial-tf)")
    pm.add_argument("--photons", type=_photons, help="photon paths per iteration (default: one per pixel); "
                    "auto (sppm): balanced against the camera pass from the error and work of each, "
                    "measured as it renders (docs/effort.md)")
    pm.add_argument("--camera-paths", type=_camera_paths,
                    help="camera paths per pixel per pass, or auto: as many as the photon pass is worth, "
                         "from the same balance (default: 1 for sppm, auto for visibility and spatial-tf; "
                         "mbe: default auto, the camera subpaths per pixel its chains meet, docs/mbe.md)")
    pm.add_argument("--alpha", type=float, help="fraction of new photons kept by the radius update (default 2/3)")
    pm.add_argument("--radius", type=float, help="initial gather radius in scene units "
                                                 "(default: 2 pixel footprints at each pixel's first hit)")
    pm.add_argument("--radius-rule", choices=["progressive", "balanced"],
                    help="progressive: the radius shrinks by alpha's rule; balanced (the default): it shrinks "
                         "faster while the radius bias, measured against discs of half the area, outweighs "
                         "what a smaller radius adds in noise (docs/vcm.md, docs/guiding.md)")
    pm.add_argument("--disc", choices=["full", "clipped", "linear", "sealed"],
                    help="sppm, visibility, spatial-tf: full divides a point's photons by its whole disc; clipped "
                         "by the part of the disc on its surface, found with rays (no dark edges; docs/guiding.md, "
                         "\"Discs that overhang an edge\"); linear: clipped, its photons weighted so that a "
                         "density linear across the disc is read at its centre; sealed: only the photons on the point's "
                         "side of the walls in its disc (no light leaking through a thin wall), divided by that "
                         "part of the disc (docs/guiding.md, \"Light that leaks through a partition\")")
    _add_guiding_options(r)
    _add_vcm_options(r)
    d = r.add_argument_group("several processes or machines (needs photonmc[distributed], i.e. Ray)")
    d.add_argument("--workers", type=int, help="independent renders (seed streams) merged into one image")
    d.add_argument("--address", help="Ray cluster to join (default: start one on this machine)")
    d.add_argument("--sync-interval", type=float, default=1.0, metavar="SECONDS",
                   help="how often each worker sends its state to be merged (default 1; a worker that "
                        "dies loses what it did since)")
    r.add_argument("-D", dest="defines", action="append", type=_define, default=[], metavar="NAME=VALUE",
                   help="set a scene parameter ($NAME), overriding its <default>")


def _add_guiding_options(parser):
    g = parser.add_argument_group("Markov chains (visibility, spatial-tf; mbe takes --chains and --target-acceptance)")
    g.add_argument("--chains", type=int, help="parallel Markov-chain ladders (default 4)")
    g.add_argument("--target-acceptance", type=float,
                   help="acceptance rate the mutation size adapts to (default 0.234)")
    g.add_argument("--proposal-failures", choices=["keep", "drop"],
                   help="keep (default): a rejected proposal repeats the current state, as Metropolis-Hastings "
                        "requires; drop: the remedy of Zeng & Wei 2019, which is biased (docs/guiding.md)")
    g.add_argument("--expected-values", action="store_true", default=None,
                   help="splat proposals with their acceptance probability (Rao-Blackwellised)")
    g.add_argument("--suffix-mutation", type=float,
                   help="probability that a mutation redraws the path from a bounce on instead of perturbing "
                        "every coordinate (docs/guiding.md, 'Why the mutations shrink')")
    g.add_argument("--mutation", choices=["joint", "blocks"],
                   help="joint (default): a mutation perturbs every coordinate with one width; blocks: one "
                        "block (light, bounce 1, bounce 2, the rest) at a time, each with its own width")
    g.add_argument("--pss-guide", type=int, choices=[0, 1, 2, 3],
                   help="pairs of a photon path's first coordinates warped by a learned guide: 1 the emission "
                        "direction, 2 and the first bounce's, 3 and the light choice (docs/guiding.md, "
                        "'A learned warp of the first coordinates'); default 0")
    g.add_argument("--path-target", choices=["max", "sum"],
                   help="spatial-tf: a path's target is the max (default) or sum of the importance of the points it hits")
    g.add_argument("--spatial-levels", type=int, choices=[2, 3],
                   help="spatial-tf: 3 (default) ladders visibility -> inverse area -> spatial importance; "
                        "2 leaves out the inverse-area level")
    g.add_argument("--spatial-updates", choices=["pass", "epochs"],
                   help="spatial-tf: pass (default): the upper levels' targets follow each pass's points and "
                        "the ladders start again every pass, discarding its first half; epochs: the targets are "
                        "held from one epoch start (after 0, 1, 2, 4, 8, ... chain passes) to the next, and the ladders "
                        "keep their states between (measured, not the default: docs/guiding.md, 'Spatial "
                        "targets held for an epoch')")


def _add_vcm_options(parser):
    g = parser.add_argument_group("vertex connection and merging (vcm, mbe; --alpha and --radius as above, "
                                  "default alpha 0.75 and 2 pixel footprints at the median first-hit distance)")
    g.add_argument("--light-paths", type=_light_paths,
                   help="vcm: light subpaths per iteration, or auto (the default): as many as a pass is worth, "
                        "measured as the render goes, at most one per pixel; mbe: chain steps per iteration "
                        "(default: one per pixel)")
    g.add_argument("--techniques", help="vcm only: vcm (default: all), bpt (no merging), bpm (merging only), "
                                        "lt (light tracing only)")
    g.add_argument("--mis", choices=["modified", "plain"],
                   help="mbe: plain (default) keeps VCM's weights; modified counts the camera-only techniques "
                        "b_V times, as the chains' light subpaths have density 1/b_V (docs/mbe.md)")
    g.add_argument("--large-step", type=float,
                   help="mbe: probability that a chain step is a uniform proposal (default 0.3; 0: every "
                        "chain moves every step)")
    g.add_argument("--warm-start", action=argparse.BooleanOptionalAction, default=None,
                   help="mbe: a contribution chain starts each pass from its last state where that still "
                        "contributes (default); --no-warm-start: from a bootstrap resampled in the pass "
                        "(docs/mbe.md). spatial-tf: its upper levels likewise (default off; measured in "
                        "docs/guiding.md; --spatial-updates epochs always keeps them)")
    g.add_argument("--uniform-weight", metavar="auto|B",
                   help="mbe, visibility, spatial-tf: the share carried by the uniform proposals' own "
                        "estimate (plain Monte Carlo: vcm's light subpaths, sppm's photons) against the "
                        "chains': auto (default) picks the share of least variance from the even and odd "
                        "ladders, and gives the uniform proposals at least that share of mbe's steps (the "
                        "guided methods mutate with probability 1 - share); 0: the chains' estimate alone; "
                        "1: the uniform proposals' alone (docs/mbe.md, docs/guiding.md)")
    g.add_argument("--uniform-passes", choices=["auto", "off"],
                   help="visibility, spatial-tf: auto (default) makes a pass a uniform pass (its photons traced "
                        "plainly, as sppm's, without the chains) where the chains' lower photon variance does not "
                        "pay for their work, both counted as the render goes; off: chain passes only "
                        "(docs/guiding.md, 'Uniform passes where the chains do not pay')")
    g.add_argument("--pass-length", choices=["balanced", "regenerations"],
                   help="visibility, spatial-tf, mbe: balanced (default) makes a chain pass last until each "
                        "chain has met up to 10 visible uniform proposals (mbe: 16), fewer (down to 1/4; mbe: 1) where the "
                        "effort balance says the camera side gains more from shorter passes than the chains "
                        "lose; regenerations: always 10 (mbe: 16) (docs/guiding.md, 'Guided passes as long as "
                        "the camera side allows'; docs/mbe.md, 'Chain passes as long as the camera side allows')")
    g.add_argument("--vcm-passes", choices=["auto", "measured", "off"],
                   help="mbe: measured (default) makes a pass a vcm pass (independent light subpaths, no "
                        "chains) where both kinds' measured variance per pass x work says it removes more error "
                        "(vcm passes measured first where chain passes are predicted to win; a measured ratio "
                        "within its error of 1 is combined with the prediction; docs/mbe.md, stops 42-43); "
                        "auto: the same choice as the chain passes' measurements predict it; off: chain passes "
                        "only (docs/mbe.md, 'vcm passes where the chains do not pay')")
    g.add_argument("--film-weights", choices=["variance", "equal"],
                   help="mbe: how the image combines the chain passes' film and the vcm passes': by their "
                        "measured variances per pass, moved toward equal weights by those estimates' errors "
                        "(variance, default), or every pass alike (equal) (docs/mbe.md, 'Two films')")
    g.add_argument("--balance", choices=["mse", "relmse"],
                   help="mbe, sppm, visibility, spatial-tf: what the effort balance behind --camera-paths auto "
                        "(and sppm's --photons auto) minimises: the image's MSE (default) or its relative MSE, each "
                        "pixel's error weighted by 1 / (its running mean^2 + (0.1 x the image's mean)^2) "
                        "(docs/mbe.md, docs/guiding.md)")
    g.add_argument("--camera-variance", choices=["twins", "pairs", "auto"],
                   help="sppm, visibility, spatial-tf: where the effort balance reads the camera side's variance "
                        "under stratified pixel positions: from twin camera paths at the same positions, plus what "
                        "the positions' stratification leaves after the paths so far (twins; sppm's default), or "
                        "from consecutive passes (pairs; visibility's and spatial-tf's default), or for those two "
                        "twins in the passes whose length is the photon floor and pairs where the chains' "
                        "regeneration sets it (auto; sppm: twins) (docs/effort.md, 'Twin camera paths', "
                        "'Twins where K does not set the pass length')")


def _method_options(args) -> dict:
    return {"photons": args.photons, "camera_paths": args.camera_paths, "alpha": args.alpha, "radius": args.radius,
            "radius_rule": args.radius_rule, "disc": args.disc, "chains": args.chains,
            "target_acceptance": args.target_acceptance, "proposal_failures": args.proposal_failures,
            "expected_values": args.expected_values, "path_target": args.path_target,
            "spatial_levels": args.spatial_levels, "spatial_updates": args.spatial_updates,
            "light_paths": args.light_paths, "techniques": args.techniques, "mis": args.mis,
            "large_step": args.large_step, "suffix_mutation": args.suffix_mutation,
            "mutation": args.mutation, "warm_start": args.warm_start,
            "balance": args.balance, "uniform_weight": args.uniform_weight, "vcm_passes": args.vcm_passes,
            "uniform_passes": args.uniform_passes, "pass_length": args.pass_length,
            "film_weights": args.film_weights, "pixel_samples": args.pixel_samples,
            "camera_variance": args.camera_variance, "pss_guide": args.pss_guide}


def _seed_list(text: str) -> list[int]:
    try:
        seeds = [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a comma-separated list of integers") from None
    if not seeds or len(set(seeds)) != len(seeds):
        raise argparse.ArgumentTypeError(f"'{text}': give distinct seeds")
    return seeds


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
                        args.out, seeds=args.seeds or [args.seed], options=options, max_depth=args.max_depth,
                        log=lambda msg: print(msg, file=sys.stderr), interleave=args.interleave)
    print(table)
    print(f"wrote {args.out}/convergence.csv, convergence.png, convergence.md", file=sys.stderr)
    return 0


def _job(args):
    from .loop import Job
    return Job(scene=args.scene, params=dict(args.defines), method=args.method or "pt", seed=args.seed or 0,
               max_depth=args.max_depth, arch=args.arch, threads=args.threads, options=_method_options(args),
               workers=args.workers, address=args.address, sync_interval=args.sync_interval)


def _resumed(args):
    """The member renders of --resume's state; the state decides the scene and settings."""
    from . import state
    given = [name for name, value in (("a scene", args.scene), ("--method", args.method), ("--seed", args.seed),
                                      ("--max-depth", args.max_depth), ("-D", args.defines))
             if value not in (None, [])]
    given += ["--" + k.replace("_", "-") for k, v in _method_options(args).items() if v is not None]
    if given:
        raise PhotonmcError(f"--resume takes the scene and settings from the state; do not give {', '.join(given)}")
    return state.load(args.resume)


def cmd_render(args) -> int:
    from . import imageio
    from .loop import Budget

    if args.out is None:
        args.out = str(Path(args.resume).with_suffix(".exr")) if args.resume else "render.exr"
    out = imageio.check_output_path(args.out)
    if args.stats and not Path(args.stats).resolve().parent.is_dir():
        raise PhotonmcError(f"directory for --stats '{args.stats}' does not exist")
    if not (args.checkpoint >= 0):
        raise PhotonmcError(f"--checkpoint must be >= 0 seconds, got {args.checkpoint}")
    budget = Budget(time=args.time, iterations=args.iterations)
    members = _resumed(args) if args.resume else None
    if args.workers is not None or args.address is not None or (members is not None and len(members) > 1):
        return _render_distributed(args, out, budget, members)
    return _render_here(args, out, budget, members[0] if members else None)


def _render_here(args, out, budget, member) -> int:
    from . import imageio, state
    from .loop import resume, run, safe_image

    if member is not None:
        prepared, job = resume(member, arch=args.arch, threads=args.threads)
    else:
        job = _job(args)
        prepared = job.prepare()
    for w in prepared.scene.warnings:
        print(f"photonmc: warning: {w}", file=sys.stderr)
    state_path = out.with_suffix(".state")

    def metadata(iterations):
        return {"method": job.method, "seed": job.seed, "iterations": iterations, "scene": prepared.scene.path}

    def save_state(method, elapsed):
        state.save(state_path, [state.state_of(method, job.identity(), prepared.scene, elapsed)])

    last_write = [time.perf_counter()]

    def checkpoint(method, iteration, elapsed):
        if args.checkpoint > 0 and time.perf_counter() - last_write[0] >= args.checkpoint:
            imageio.write_image(out, safe_image(method.image()), metadata(iteration))
            save_state(method, elapsed)
            last_write[0] = time.perf_counter()

    result = run(prepared, budget, quiet=args.quiet, on_iteration=checkpoint)
    written = imageio.write_image(out, result.image, metadata(result.stats["iterations"]))
    save_state(prepared.method, result.stats["wall_seconds"]["render"])
    written.append(state_path)
    stats = result.stats
    if stats.get("nonfinite_samples_dropped") or stats.get("nonfinite_pixels_zeroed"):
        print(f"photonmc: warning: {stats.get('nonfinite_samples_dropped', 0)} NaN/Inf samples dropped, "
              f"{stats['nonfinite_pixels_zeroed']} non-finite pixels set to 0", file=sys.stderr)
    return _finish(args, stats, written, result.interrupted)


def _finish(args, stats, written, interrupted) -> int:
    if args.stats:
        Path(args.stats).write_text(json.dumps(stats, indent=2) + "\n")
    if not args.quiet:
        how = "interrupted after" if interrupted else "finished"
        print(f"photonmc: {how} {stats['iterations']} iterations in {stats['wall_seconds']['render']:.1f} s; "
              f"wrote {', '.join(str(p) for p in written)}", file=sys.stderr)
    return 130 if interrupted else 0


def _render_distributed(args, out, budget, members) -> int:
    from . import distributed
    from .loop import Job

    if members is not None:
        job = Job.from_identity(members[0].job, arch=args.arch, threads=args.threads)
    else:
        job = _job(args)
    job.workers = args.workers if args.workers is not None else (len(members) if members else 1)
    job.address, job.sync_interval = args.address, args.sync_interval
    result = distributed.run(job, budget, resumed=members, out=out, checkpoint=args.checkpoint, quiet=args.quiet)
    for line in result.events:
        print(f"photonmc: warning: {line}", file=sys.stderr)
    return _finish(args, result.stats, result.written, result.interrupted)


def cmd_merge(args) -> int:
    from . import imageio, merge, state
    from .loop import safe_image

    out = imageio.check_output_path(args.out)
    members = [m for path in args.states for m in state.load(path)]
    merge.check_mergeable(members)
    summary = merge.summary(members)
    written = imageio.write_image(out, safe_image(merge.merged_image(members)),
                                  {"method": summary["method"], "seeds": summary["seeds"],
                                   "iterations": summary["iterations"], "scene": members[0].job["scene"]})
    written.append(state.save(out.with_suffix(".state"), members))
    print(f"photonmc: merged {len(members)} renders ({summary['iterations']} iterations of {summary['method']}); "
          f"wrote {', '.join(str(p) for p in written)}", file=sys.stderr)
    return 0


def cmd_preview(args) -> int:
    from .loop import Budget, default_scene_path
    from .methods import method_class
    from .loop import Job
    from .preview import preview
    from .scene import load_scene

    method_class(args.method or "pt")
    params = dict(args.defines)
    scene_path = str(args.scene or default_scene_path())
    scene = load_scene(scene_path, params)      # fail here, before a window opens, on a bad scene
    for w in scene.warnings:
        print(f"photonmc: warning: {w}", file=sys.stderr)
    budget = Budget(time=args.time, iterations=args.iterations,
                    until_stopped=args.time is None and args.iterations is None)
    job = Job(scene=scene_path, params=params, method=args.method or "pt", budget=budget, seed=args.seed or 0,
              max_depth=args.max_depth, arch=args.arch, threads=args.threads, options=_method_options(args),
              workers=args.workers, address=args.address, sync_interval=args.sync_interval)
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
        if args.command == "merge":
            return cmd_merge(args)
    except PhotonmcError as e:
        print(f"photonmc: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("photonmc: aborted", file=sys.stderr)
        return 130
    return 1


if __name__ == "__main__":
    sys.exit(main())
