"""The compiler settings of photonmc/runtime.py change how long kernels take to compile, not
what they compute beyond float rounding (docs/performance.md, "Compile time")."""
import json
import subprocess
import sys

import numpy as np
from taichi.lang import impl

import photonmc

from .conftest import REPO

RENDER = dict(method="pt", iterations=2, seed=5, params={"res": "16"})

# A second process, since Taichi is initialised once per process: the same render with
# Taichi's CFG optimisation passes on, as before runtime.py turned them off.
WITH_CFG_OPTIMISATION = f"""
import json, sys
import numpy as np
import taichi as ti
sys.path.insert(0, {str(REPO)!r})
original = ti.init
ti.init = lambda **kwargs: original(**{{**kwargs, "cfg_optimization": True}})
import photonmc
image = photonmc.render(**json.loads(sys.argv[1]))
assert ti.lang.impl.current_cfg().cfg_optimization
np.save(sys.argv[2], image)
"""


def test_runtime_turns_the_cfg_passes_off():
    assert impl.current_cfg().cfg_optimization is False


def test_cfg_optimisation_changes_rounding_only(tmp_path):
    """The passes forward stores to loads before LLVM sees the code; with fast math, LLVM may
    then contract or reorder float operations differently, so images may differ in the last
    bits (and a Markov chain whose acceptance test falls on such a bit then takes another,
    equally valid, path). pt has no such decision at these settings: its images must agree
    to float rounding."""
    out = tmp_path / "with_cfg.npy"
    subprocess.run([sys.executable, "-c", WITH_CFG_OPTIMISATION, json.dumps(RENDER), str(out)], check=True,
                   capture_output=True, timeout=600)
    with_passes = np.load(out)
    without = photonmc.render(**RENDER)
    assert with_passes.shape == without.shape
    scale = float(np.abs(with_passes).max())
    assert scale > 0.0
    np.testing.assert_allclose(without, with_passes, rtol=0, atol=1e-5 * scale)
