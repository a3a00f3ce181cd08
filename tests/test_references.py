"""Citations: papers are named by author and year in everything a user reads (never by the internal file
numbers of the development repository, "seed 000" .. "seed 004"), every public object that implements a
published method carries a numpydoc References section, and every reference there is worded exactly as
in docs/references.md, the one full list."""

from __future__ import annotations

import importlib
import inspect
import pkgutil
import re
from pathlib import Path

import pytest
from typer.testing import CliRunner

import mptrack

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src" / "mptrack"
#: a citation by file number: "seed 000", "seeds 000/002", "Seed 004", "seed000"
FILE_NUMBER = re.compile(r"\bseeds? ?00\d", re.IGNORECASE)

A14, A15, A16, B17, Z13 = ("Assimakis & Adam 2014", "Assimakis & Adam 2015", "Assimakis et al. 2016",
                           "Bouzera et al. 2017", "Zhao et al. 2013")
KAL, LAI, RTS, VL = "Kalman 1960", "Lainiotis 1975", "Rauch et al. 1965", "Van Loan 1978"
BS, COST, HATA, TMN = "Bar-Shalom et al. 2001", "COST 231 1999", "Hata 1980", "Tichavský et al. 1998"
#: the public objects that implement a published method (or the papers' models, formulas and examples),
#: with the works their References section lists, in order (short names of docs/references.md)
CITES = {
    "mptrack.linear.kalman_filter": (A14, KAL),
    "mptrack.linear.kalman_step": (A14, KAL),
    "mptrack.linear.lainiotis_filter": (A14, LAI),
    "mptrack.linear.lainiotis_step": (A14, LAI),
    "mptrack.linear.steady_state_filter": (A14,),
    "mptrack.linear.fir_filter": (A14,),
    "mptrack.linear.fir_order": (A14,),
    "mptrack.linear.fir_coefficients": (A14,),
    "mptrack.linear.join_results": (A14,),
    "mptrack.linear.per_axis": (A14,),
    "mptrack.linear.Implementation": (A14, A15),
    "mptrack.linear.get_implementation": (A14, A15),
    "mptrack.linear.steady_state_predictor": (A16,),
    "mptrack.linear.prediction_matrices": (A16,),
    "mptrack.linear.predict_ahead": (A16,),
    "mptrack.linear.rts_smoother": (RTS,),
    "mptrack.linear.steady_state_smoother": (RTS,),
    "mptrack.linear.kalman_filter_irregular": (A16, VL),
    "mptrack.linear.rts_smoother_irregular": (RTS,),
    "mptrack.batch.steady_state_filter": (A14,),
    "mptrack.batch.kalman_filter": (A14, KAL),
    "mptrack.batch.fir_filter": (A14,),
    "mptrack.batch.per_axis": (A14,),
    "mptrack.batch.gain_sequence": (A14, KAL),
    "mptrack.batch.ekf_ranges": (B17,),
    "mptrack.burden.filter_burden": (A14, A15),
    "mptrack.burden.join_burden": (A14, A15),
    "mptrack.burden.implementation_burden": (A14, A15),
    "mptrack.burden.fir_burden": (A14,),
    "mptrack.burden.fir_break_even": (A14,),
    "mptrack.burden.speedup": (A14, A15),
    "mptrack.models.stack_axes": (A14,),
    "mptrack.models.assimakis_model_a": (A14, A15),
    "mptrack.models.assimakis_model_b": (A14, A15),
    "mptrack.models.ContinuousLinearModel": (A16,),
    "mptrack.models.van_loan": (VL,),
    "mptrack.models.discretize": (A16, VL),
    "mptrack.models.discretize_intervals": (VL,),
    "mptrack.models.constant_velocity_continuous": (A16,),
    "mptrack.models.constant_acceleration_continuous": (A16,),
    "mptrack.models.constant_velocity": (A16, VL),
    "mptrack.models.constant_acceleration": (A16, VL),
    "mptrack.models.cv_discrete_white_noise": (BS, A14),
    "mptrack.models.ca_discrete_white_noise": (BS,),
    "mptrack.riccati.SteadyState": (A14,),
    "mptrack.riccati.steady_state": (A14,),
    "mptrack.riccati.riccati_step": (A14,),
    "mptrack.riccati.LainiotisParameters": (A14, LAI),
    "mptrack.riccati.lainiotis_parameters": (A14, LAI),
    "mptrack.metrics.position_error": (B17,),
    "mptrack.metrics.nees": (BS,),
    "mptrack.metrics.pcrb": (TMN,),
    "mptrack.metrics.pcrb_tichavsky": (TMN,),
    "mptrack.metrics.range_fisher_information": (TMN,),
    "mptrack.metrics.pcrb_ranges": (TMN, B17),
    "mptrack.cellular.range_measurement": (B17,),
    "mptrack.cellular.motion_matrix": (B17,),
    "mptrack.cellular.ekf_ranges": (B17,),
    "mptrack.cellular.ekf_ranges_batch": (B17,),
    "mptrack.cellular.fekf_ranges": (B17,),
    "mptrack.cellular.fekf_ranges_batch": (B17,),
    "mptrack.cellular.fcs_ranges": (B17,),
    "mptrack.cellular.fcs_ranges_batch": (B17,),
    "mptrack.cellular.bouzera_fekf_fis": (B17,),
    "mptrack.cellular.bouzera_fcs_fis": (B17,),
    "mptrack.cellular.local_solutions": (B17,),
    "mptrack.cellular.fuse_local_solutions": (B17,),
    "mptrack.continuous.ContinuousDiscreteModel": (Z13, "Hutzenthaler et al. 2012"),
    "mptrack.continuous.zhao2013_model": (Z13, "Beard et al. 1999"),
    "mptrack.continuous.FEMGrid": (Z13,),
    "mptrack.continuous.fem_filter": (Z13,),
    "mptrack.continuous.fem_steps": (Z13, "Brooks & Hughes 1982"),
    "mptrack.continuous.shape_functions": (Z13,),
    "mptrack.continuous.reference_filter": ("Gordon et al. 1993",),
    "mptrack.nonlinear.ekf_filter": ("Särkkä 2013",),
    "mptrack.nonlinear.ekf_smoother": ("Särkkä 2013",),
    "mptrack.nonlinear.ekf_step": ("Särkkä 2013",),
    "mptrack.nonlinear.ekf_filter_batch": ("Särkkä 2013",),
    "mptrack.nonlinear.ukf_filter": ("Julier 2002", "Wan & van der Merwe 2000", "Särkkä 2007"),
    "mptrack.nonlinear.ukf_smoother": ("Särkkä 2008",),
    "mptrack.nonlinear.sigma_points": ("Julier 2002",),
    "mptrack.nonlinear.particle_filter": ("Gordon et al. 1993", "Kitagawa 1996", "Musso et al. 2001"),
    "mptrack.nonlinear.systematic_resample": ("Kitagawa 1996",),
    "mptrack.nonlinear.imm_filter": ("Blom & Bar-Shalom 1988",),
    "mptrack.nonlinear.cv_ca_models": ("Blom & Bar-Shalom 1988", BS),
    "mptrack.fuzzy.TakagiSugeno": ("Takagi & Sugeno 1985",),
    "mptrack.fuzzy.anfis_train": ("Jang 1993", B17),
    "mptrack.fuzzy.fused_covariance_prop3": (B17,),
    "mptrack.fuzzy.fused_covariance_trace": (B17,),
    "mptrack.fuzzy.probabilistic_fusion": (B17,),
    "mptrack.radio.arfcn_to_frequency": ("3GPP TS 45.005", B17),
    "mptrack.radio.path_loss_from_rss": (B17,),
    "mptrack.radio.distance_from_rss": (B17,),
    "mptrack.radio.wi_free_space_loss": (COST, "3GPP TR 25.996", B17),
    "mptrack.radio.wi_orientation_loss": (COST, B17),
    "mptrack.radio.wi_rooftop_to_street_loss": (COST,),
    "mptrack.radio.wi_multiscreen_loss": (COST,),
    "mptrack.radio.cost231_wi_los": (COST, B17),
    "mptrack.radio.cost231_wi_nlos": (COST, "3GPP TR 25.996", B17),
    "mptrack.radio.cost231_hata": (COST,),
    "mptrack.radio.okumura_hata": (HATA,),
    "mptrack.radio.hata_mobile_correction": (HATA,),
    "mptrack.linear.fit_em": ("Shumway & Stoffer 1982", "Ghahramani & Hinton 1996", "Shumway & Stoffer 2017"),
    "mptrack.linear.fit_ml": ("Schweppe 1965", "Shumway & Stoffer 2017"),
    "mptrack.tracking.kalman_filter_gated": (BS,),
    "mptrack.tracking.nis_threshold": (BS,),
    "mptrack.tracking.rts_smoother_gated": (RTS,),
    "mptrack.tracking.track_gated": (BS,),
    "mptrack.tracking.track_fixes": (BS, "Gelb 1974"),
}


def _plain(markdown: str) -> str:
    """A reference cell of docs/references.md as plain text: no emphasis, the DOI link as ``doi:...``."""
    text = re.sub(r"\[([^\]]+)\]\(https://doi\.org/\1\)", r"\1", markdown)
    return re.sub(r"\*([^*]+)\*", r"\1", text)


def _references() -> dict[str, str]:
    """{short name: full reference (plain text)} of every table of docs/references.md."""
    out = {}
    for line in (ROOT / "docs" / "references.md").read_text().splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split(" | ")]
        if line.startswith("| ") and len(cells) >= 2 and cells[0] != "short name" and not set(cells[0]) <= set("-|"):
            out[cells[0]] = _plain(cells[1])
    return out


REFERENCES = _references()


def _public_modules():
    """mptrack and its public subpackages and modules (none whose name starts with '_')."""
    yield mptrack
    for info in pkgutil.iter_modules(mptrack.__path__, "mptrack."):
        if not info.name.rsplit(".", 1)[1].startswith("_"):
            yield importlib.import_module(info.name)


def _public_objects() -> dict[str, object]:
    """{dotted name: object} of every function and class a public module exports (``__all__``), once."""
    out, seen = {}, set()
    for module in _public_modules():
        for name in getattr(module, "__all__", ()):
            obj = getattr(module, name)
            if (inspect.isfunction(obj) or inspect.isclass(obj)) and id(obj) not in seen:
                seen.add(id(obj))
                out[f"{module.__name__}.{name}"] = obj
    return out


PUBLIC = _public_objects()


def _docstrings():
    """(where, text) of every docstring a user reads: public modules, objects and their public methods."""
    for module in _public_modules():
        yield module.__name__, module.__doc__ or ""
    for name, obj in PUBLIC.items():
        yield name, inspect.getdoc(obj) or ""
        if inspect.isclass(obj):
            for attr, member in vars(obj).items():
                if not attr.startswith("_") and (inspect.isfunction(member) or isinstance(member, property)):
                    yield f"{name}.{attr}", inspect.getdoc(member) or ""


def _cli_help() -> list[tuple[str, str]]:
    from mptrack.cli import app

    runner = CliRunner()
    commands = ["", "track", "simulate", "evaluate", "reproduce", "bench", "filters"]
    return [(f"mptrack {c} --help", runner.invoke(app, [*c.split(), "--help"]).output) for c in commands]


def _section(doc: str) -> list[str] | None:
    """The entries of the numpydoc References section of ``doc`` (whitespace collapsed), or None; the
    section ends at the next one (numpydoc puts Examples after References) or at the end."""
    m = re.search(r"^References\n-{10}\n(.*?)(?=^\w[\w ]*\n-+\n|\Z)", doc, flags=re.S | re.M)
    if m is None:
        return None
    entries = re.split(r"^\.\. \[(\d+)\] ", m.group(1), flags=re.M)
    numbers, texts = entries[1::2], entries[2::2]
    assert not entries[0].strip() and numbers == [str(i) for i in range(1, len(numbers) + 1)], \
        f"References entries must be '.. [1] ', '.. [2] ', ...: {m.group(1)[:200]!r}"
    return [" ".join(t.split()) for t in texts]


def test_user_text_names_papers_by_author_and_year():
    """No docstring, CLI help, guide, README, registry text or source comment cites a paper by the
    development repository's file number."""
    texts = list(_docstrings()) + _cli_help()
    texts += [(p.name, p.read_text()) for p in [*sorted((ROOT / "docs").glob("*.md")), ROOT / "README.md"]]
    texts += [(str(p.relative_to(ROOT)), p.read_text()) for p in sorted(SRC.rglob("*.py"))]
    from mptrack.experiments import experiments
    from mptrack.linear import FILTERS

    texts += [(f"experiment {k}", f"{e.paper} {e.description}") for k, e in experiments().items()]
    texts += [(f"filter {k}", str(s)) for k, s in FILTERS.items()]
    bad = [(where, line.strip()[:120]) for where, text in texts for line in text.splitlines()
           if FILE_NUMBER.search(line)]
    assert not bad, f"{len(bad)} citations by file number, e.g. {bad[:5]}"


def test_the_full_references_list_covers_the_papers():
    """docs/references.md gives every paper the code cites by author and year, with the venue the
    publisher assigned (Zhao et al. 2013 is in Mathematical Problems in Engineering)."""
    for short in (A14, A15, A16, B17, Z13):
        assert short in REFERENCES
    assert "Mathematical Problems in Engineering" in REFERENCES[Z13]
    assert "doi:10.1155/2013/175425" in REFERENCES[Z13]
    for path in (SRC / "experiments" / "zhao2013.py", SRC / "experiments" / "data" / "zhao2013.json"):
        text = path.read_text()
        assert "Journal of Applied Mathematics" not in text and "965326" not in text
        assert "Mathematical Problems in Engineering" in text


@pytest.mark.parametrize("name", list(CITES))
def test_paper_methods_list_their_references(name):
    obj = PUBLIC.get(name)
    assert obj is not None, f"{name} is not a public object"
    entries = _section(inspect.getdoc(obj) or "")
    assert entries is not None, f"{name}: no numpydoc 'References' section"
    assert entries == [REFERENCES[k] for k in CITES[name]], f"{name}: References differ from docs/references.md"


def test_every_reference_in_a_docstring_is_worded_as_in_the_full_list():
    """One wording per work: each References entry of any public docstring is a docs/references.md entry,
    and a docstring that names a work by its short name lists it."""
    full = set(REFERENCES.values())
    bad = []
    for where, doc in _docstrings():
        entries = _section(doc) or []
        bad += [(where, e[:80]) for e in entries if e not in full]
        flat = " ".join(doc.split())
        bad += [(where, f"names {short} but does not list it") for short, ref in REFERENCES.items()
                if re.search(rf"(?<![\w-]){re.escape(short)}\b", flat) and ref not in entries
                and where in PUBLIC]
    assert not bad, bad
