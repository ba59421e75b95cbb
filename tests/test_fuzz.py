"""A few hundred seeded mutations of the shipped scenes, fiber files, hair controls, targets and photos
(helpers/fuzz.py; benchmarks/fuzz.py runs thousands, each in a child process with limits): every outcome is an
error naming the input, a finite render of an input that loads, or a photo (a damaged one only where it is a
JPEG, which has no checksum)."""

from collections import Counter

import pytest
from helpers import fuzz

CASES = 300
PHOTO_CASES = 60  # decoded photos: a few milliseconds each


@pytest.fixture(scope="module")
def outcomes(tmp_path_factory):
    workdir = tmp_path_factory.mktemp("fuzz")
    mutants = fuzz.cases(seed=2026, n=CASES, areas=fuzz.FILE_AREAS)
    mutants += fuzz.cases(seed=2026, n=PHOTO_CASES, areas=fuzz.PHOTO_AREAS, first=CASES)
    return [(case, fuzz.run_case(case, workdir)) for case in mutants]


def test_every_outcome_is_a_named_error_or_a_finite_render(outcomes):
    failures = [
        f"#{c.index} {c.area} {c.source}: {c.mutation} -> {o}: {d[:200]}"
        for c, (o, d) in outcomes
        if o not in fuzz.PASSING
    ]
    assert not failures, "\n".join(failures)


def test_the_cases_cover_every_area_and_both_kinds_of_outcome(outcomes):
    """A fuzz whose mutations all fail to load (or all load) would test little: both must occur in each area."""
    counts = Counter((case.area, outcome) for case, (outcome, _) in outcomes)
    for area in fuzz.AREAS:
        assert counts[(area, "error naming the input")] > 0, area
        assert sum(n for (a, o), n in counts.items() if a == area and o != "error naming the input") > 0, area


def test_the_cases_are_reproducible():
    a, b = fuzz.cases(seed=5, n=40), fuzz.cases(seed=5, n=40)
    assert [(c.area, c.mutation) for c in a] == [(c.area, c.mutation) for c in b]


def test_the_isolation_reports_a_dying_child(tmp_path, monkeypatch):
    """A case that exhausts its memory limit, or dies, is an outcome of its own, not a dead fuzz run."""
    case = fuzz.cases(seed=1, n=1)[0]

    def hungry(case, workdir):
        return ("image", str(len(bytearray(2**34))))  # 16 GiB: beyond the 64 MiB allowed

    monkeypatch.setattr(fuzz, "run_case", hungry)
    started = fuzz.start_isolated(case, tmp_path, memory=64 * 2**20, seconds=20)
    outcome = None
    while outcome is None:
        outcome = fuzz.finish_isolated(*started)
    assert outcome[0] == "crash" and "MemoryError" in outcome[1]
