"""How fast the film's camera error falls under stratified pixel positions, against the model
sppm's effort balance uses (docs/effort.md, "Twin camera paths").

    python tools/position_variance.py SCENE [-D res=32] [--seeds 16] [--marks 8,32,128,512]
                                      [--photons 16384]

Renders sppm with a fixed photon count and radii held (alpha 0.999, so that a pass's photon
variance does not grow) over several seeds, with twin camera paths traced although nothing
steers by them. After M passes it prints the film's variance over seeds (mean over pixels of
luminance) beside what the balance's terms predict:
- (V_held + V_p / n) / M: the twins' V_c (pixel positions held) and the photons' variance, both
  falling as 1 / M;
- V_pos M^-1.5: the positions' variance per path (the consecutive passes' V_c less the twins'),
  falling as a scrambled net's mean does over a pixel whose value jumps along edges;
- c: the factor on V_pos M^-1.5 that the film's variance implies (about 1 if the model holds);
- V_pos / M: what the consecutive passes' V_c alone would predict.
"""
import argparse
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from photonmc.loop import Job  # noqa: E402

LUMINANCE = np.array([0.2126, 0.7152, 0.0722])


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("scene")
    ap.add_argument("-D", dest="defines", action="append", default=[], metavar="NAME=VALUE")
    ap.add_argument("--seeds", type=int, default=16)
    ap.add_argument("--marks", default="8,32,128,512")
    ap.add_argument("--photons", type=int, default=16384)
    args = ap.parse_args()
    params = dict(d.split("=", 1) for d in args.defines) or {"res": "32"}
    marks = sorted(int(m) for m in args.marks.split(","))
    films = {m: [] for m in marks}
    held = pairs = v_p = 0.0
    for seed in range(args.seeds):
        p = Job(scene=args.scene, params=dict(params), method="sppm", seed=seed,
                options={"photons": args.photons, "alpha": 0.999}).prepare()
        m = p.method
        try:
            # twins although the photon count is fixed: what the balance would read
            m.held_camera = True
            m.effort = m._new_effort()
            for it in range(1, marks[-1] + 1):
                m.iterate()
                if it in films:
                    films[it].append(m.image() @ LUMINANCE)
            e = m.effort
            held += e.camera_sum / e.samples
            pairs += e.pair_sum / e.pair_samples
            v_p += e.shares()[1]
        finally:
            p.release()
    held, pairs, v_p = held / args.seeds, pairs / args.seeds, v_p / args.seeds
    v_pos = pairs - held
    print(f"{args.scene} {params}, {args.seeds} seeds: V_c twins {held:.4g}, consecutive passes {pairs:.4g}, "
          f"V_pos {v_pos:.4g}, V_p / n {v_p / args.photons:.4g}\n")
    print("| M | film variance over seeds | (V_held + V_p/n) / M | V_pos M^-1.5 | c | V_pos / M |")
    print("|---|---|---|---|---|---|")
    for mark in marks:
        film = float(np.var(np.array(films[mark]), axis=0, ddof=1).mean())
        base = (held + v_p / args.photons) / mark
        position = v_pos * mark ** -1.5
        print(f"| {mark} | {film:.4g} | {base:.4g} | {position:.4g} | {(film - base) / position:.3g} | "
              f"{v_pos / mark:.4g} |")


if __name__ == "__main__":
    main()
