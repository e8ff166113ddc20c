"""Time per pass of a photon method under the two radius rules, alternated in one process so
that the host's drift cancels (docs/guiding.md, "The balanced radius with the history's ratios").

    python tools/radius_rule_time.py SCENE [-D res=64] [--method sppm] [--rounds 6] [--passes 100]

Prints each rule's milliseconds per pass, the passes the balanced rule shrank faster and
the mean radius at the end.
"""
import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from photonmc import load_scene  # noqa: E402
from photonmc.loop import prepare  # noqa: E402


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("scene")
    ap.add_argument("-D", dest="defines", action="append", default=[], metavar="NAME=VALUE")
    ap.add_argument("--method", default="sppm")
    ap.add_argument("--rounds", type=int, default=6)
    ap.add_argument("--passes", type=int, default=100)
    args = ap.parse_args()
    scene = load_scene(args.scene, dict(d.split("=", 1) for d in args.defines) or {"res": "64"})
    prepared = {rule: prepare(scene, method=args.method, seed=0, options={"radius_rule": rule})
                for rule in ("progressive", "balanced")}
    for p in prepared.values():
        p.method.warm_up()
        p.method.reset()
    seconds = dict.fromkeys(prepared, 0.0)
    for _ in range(args.rounds):
        for rule, p in prepared.items():
            t0 = time.perf_counter()
            for _ in range(args.passes):
                p.method.iterate()
            seconds[rule] += time.perf_counter() - t0
    for rule, p in prepared.items():
        s = p.method.stats()
        print(f"{rule}: {1000 * seconds[rule] / (args.rounds * args.passes):.2f} ms per pass, "
              f"shrunk faster {s.get('passes_shrunk_fast', 0)}, mean radius {s.get('mean_radius')}")
        p.release()


if __name__ == "__main__":
    main()
