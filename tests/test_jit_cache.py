"""Compiled kernels are cached in the user's cache directory and load without compiling in a new process."""

import json
import os
import subprocess
import sys
from pathlib import Path

import mptrack

PACKAGE = Path(mptrack.__file__).resolve().parent
KERNEL_MODULES = ["_core.float_scan", "_core.geodesy", "_core.kalman", "_core.rts", "batch._kernels",
                  "bench._timing", "continuous._fem_kernels", "continuous._kernels", "linear._kernels",
                  "nonlinear._named_kernels", "nonlinear._pf_kernels", "nonlinear._step_kernels", "tracking._chain",
                  "tracking._fix_error", "tracking._live", "tracking._state", "tracking._kernels",
                  "tracking._likelihood", "tracking._track_filter"]


def _python(code: str, **env) -> str:
    environ = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "MPTRACK_CACHE_DIR")}
    environ.update(env)
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=environ, timeout=600)
    assert done.returncode == 0, done.stderr
    return done.stdout


def test_every_cached_kernel_lives_outside_the_package(tmp_path):
    """Each module's cached dispatchers point into MPTRACK_CACHE_DIR (nothing is compiled for this)."""
    paths = json.loads(_python(
        "import importlib, json\n"
        "from numba.core.registry import CPUDispatcher\n"
        f"mods = {KERNEL_MODULES!r}\n"
        "paths = {}\n"
        "for name in mods:\n"
        "    mod = importlib.import_module('mptrack.' + name)\n"
        "    for attr, obj in vars(mod).items():\n"
        "        if isinstance(obj, CPUDispatcher) and obj._cache.__class__.__name__ != 'NullCache'"
        " and obj.__module__ == mod.__name__:\n"
        "            paths[name + '.' + attr] = obj._cache._cache_path\n"
        "print(json.dumps(paths))", MPTRACK_CACHE_DIR=str(tmp_path)))
    assert {name.rsplit(".", 1)[0] for name in paths} == set(KERNEL_MODULES)
    outside = {name: p for name, p in paths.items() if not Path(p).is_relative_to(tmp_path)}
    assert not outside
    assert not any(Path(p).is_relative_to(PACKAGE) for p in paths.values())


def test_numba_cache_dir_set_by_the_user_keeps_its_meaning(tmp_path):
    path = _python("from mptrack.linear._kernels import kf_loop; print(kf_loop._cache._cache_path)",
                   NUMBA_CACHE_DIR=str(tmp_path / "numba"), MPTRACK_CACHE_DIR=str(tmp_path / "ours"))
    assert Path(path.strip()).is_relative_to(tmp_path / "numba")


def test_particle_filter_starts_warm_in_a_new_process():
    """The PF's model-calling kernels take the model's kernels as addresses, so they are cached like the
    rest: a second process loads them (cache hits, no misses) for a named and for a user-made model."""
    run = (
        "import numpy as np\n"
        "from numba import njit\n"
        "from mptrack import continuous as cd\n"
        "from mptrack.nonlinear import particle_filter\n"
        "from mptrack.continuous._kernels import _advance_at, _loglik_at\n"
        "m = cd.zhao2013_model()\n"
        "x, z = cd.simulate_sde(m, 3, np.random.default_rng(0), cd.ZHAO2013_X0)\n"
        "particle_filter(m, z, cd.ZHAO2013_X0, np.eye(2), np.random.default_rng(1), particles=300)\n"
        "@njit\n"
        "def decay(X, p, out):\n"
        "    for j in range(X.shape[1]):\n"
        "        out[0, j] = -p[0] * X[0, j]\n"
        "        out[1, j] = -p[0] * X[1, j]\n"
        "own = cd.ContinuousDiscreteModel(lambda X: -0.5 * X, 0.01 * np.eye(2), lambda X: X, 0.1 * np.eye(2), 0.5,"
        " kernels=cd.BlockKernels(decay, decay, np.array([0.5]), np.array([-1.0])))\n"
        "x, z = cd.simulate_sde(own, 3, np.random.default_rng(0), np.ones(2))\n"
        "particle_filter(own, z, np.ones(2), np.eye(2), np.random.default_rng(1), particles=300)\n"
        "print(sum(_advance_at.stats.cache_misses.values()) + sum(_loglik_at.stats.cache_misses.values()),"
        " sum(_advance_at.stats.cache_hits.values()) + sum(_loglik_at.stats.cache_hits.values()))\n")
    _python(run)  # compiles once if no earlier run did
    misses, hits = map(int, _python(run).split())
    assert misses == 0 and hits >= 2
