"""The package layout by model family (issue 19) and the naming rule (issue 34): every package imports
first in a new process, and the names that moved out of mptrack.nonlinear, or were moved or renamed by
the naming rule, still import from their old place for one release: the same object, with exactly one
DeprecationWarning that names the new place."""

import subprocess
import sys
import warnings

import pytest

import mptrack.cellular as cellular
import mptrack.continuous as continuous
import mptrack.nonlinear as nonlinear
import mptrack.result as result

#: mptrack.nonlinear's public names before the split (release 0.1.0)
NONLINEAR_0_1 = (
    "BatchFilterResult", "check_stations", "ekf_ranges", "ekf_ranges_batch", "motion_matrix", "motion_position",
    "range_measurement", "range_fix", "bouzera_fekf_fis", "bouzera_fcs_fis", "fekf_ranges", "fekf_ranges_batch",
    "fcs_ranges", "fcs_ranges_batch", "fuse_local_solutions", "local_solutions", "ContinuousDiscreteModel",
    "BlockKernels", "zhao2013_model", "linear_sde_model", "simulate_sde", "ZHAO2013_X0", "FEMGrid", "GridDensity",
    "GridMixture", "FEMStep", "fem_filter", "fem_steps", "shape_functions", "ukf_filter", "ukf_smoother",
    "ekf_filter", "ekf_smoother", "ekf_step", "ekf_filter_batch", "imm_filter", "IMMResult", "cv_ca_models",
    "sigma_points", "particle_filter", "pf_substeps", "systematic_resample", "reference_filter", "pf_substep_study",
)
HOMES = {"mptrack.nonlinear": nonlinear, "mptrack.cellular": cellular, "mptrack.continuous": continuous,
         "mptrack.result": result}


def _get(module, name: str):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        value = getattr(module, name)
    return value, caught


@pytest.mark.parametrize("name", NONLINEAR_0_1)
def test_every_name_of_the_old_nonlinear_package_still_imports(name):
    """A name that stayed imports silently; a moved one is its new package's object, with one warning
    that points at the caller and names the new path."""
    value, caught = _get(nonlinear, name)
    homes = [path for path, module in HOMES.items() if name in module.__all__]
    assert len(homes) == 1, f"{name} is exported by {homes}"
    if homes == ["mptrack.nonlinear"]:
        assert not caught
        return
    assert value is getattr(HOMES[homes[0]], name)
    assert [w.category for w in caught] == [DeprecationWarning]
    assert f"moved to {homes[0]}.{name}" in str(caught[0].message)
    assert caught[0].filename == __file__


def test_the_from_import_statement_warns_and_unknown_names_still_fail():
    with pytest.warns(DeprecationWarning, match=r"mptrack\.nonlinear\.fem_filter moved to mptrack\.continuous"):
        from mptrack.nonlinear import fem_filter
    assert fem_filter is continuous.fem_filter
    with pytest.raises(ImportError):
        from mptrack.nonlinear import no_such_name  # noqa: F401
    assert not hasattr(nonlinear, "_fem")   # private modules moved without a forwarding path


@pytest.mark.parametrize("module", ["mptrack.nonlinear", "mptrack.continuous", "mptrack.cellular",
                                    "mptrack.continuous._model", "mptrack.continuous._kernels",
                                    "mptrack._core.filter_inputs", "mptrack.batch"])
def test_each_package_imports_first_in_a_new_process(module):
    """continuous depends on nonlinear (and registers its model with nonlinear's filters through
    mptrack._core.model_families); importing any of them first must work."""
    done = subprocess.run([sys.executable, "-W", "error::DeprecationWarning", "-c", f"import {module}"],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr


#: (old package, old name, new package, new name) of the names moved or renamed by the naming rule (issue 34;
#: docs/design.md, Naming rule)
RENAMED = [
    ("mptrack.batch", "range_ekf", "mptrack.batch", "ekf_ranges"),
    ("mptrack.tracking", "smooth_gated", "mptrack.tracking", "rts_smoother_gated"),
    ("mptrack.tracking", "read_output", "mptrack.io", "read_output"),
    ("mptrack.tracking", "band_of_arfcn", "mptrack.radio", "band_of_arfcn"),
    ("mptrack.tracking", "TA_STEP_M", "mptrack.radio", "TA_STEP_M"),
    ("mptrack.linear", "FilterResult", "mptrack.result", "FilterResult"),
    ("mptrack.nonlinear", "BatchFilterResult", "mptrack.result", "BatchFilterResult"),
]


@pytest.mark.parametrize("old, name, new, new_name", RENAMED)
def test_names_moved_or_renamed_by_the_naming_rule_still_import_with_a_warning(old, name, new, new_name):
    import importlib

    old_module, new_module = importlib.import_module(old), importlib.import_module(new)
    assert name not in old_module.__all__ and new_name in new_module.__all__
    value, caught = _get(old_module, name)
    assert value is getattr(new_module, new_name)
    assert [w.category for w in caught] == [DeprecationWarning]
    verb = "moved to" if name == new_name else "is now"
    assert f"{old}.{name} {verb} {new}.{new_name}" in str(caught[0].message)
    assert caught[0].filename == __file__


def test_every_public_name_has_one_home():
    """A name is exported by one public package only (docs/design.md, Naming rule): the same object
    under the same name in two packages' __all__ is refused (a constant's value may repeat)."""
    from _public import public_objects

    homes: dict = {}
    for qualified, value in public_objects(skip=("cli", "bench")).items():
        package, name = qualified.rsplit(".", 1)
        if callable(value):
            homes.setdefault((name, id(value)), []).append(package)
    shared = {name: where for (name, _), where in homes.items() if len(where) > 1}
    assert not shared, shared
