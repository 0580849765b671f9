"""Fuzz suite: every command that reads a file, run in-process on seeded corruptions of that file.

Sources and corruptions are in ``tests/fuzz/fuzz_cases.py``: a store (``info --check``, ``train``,
``curate``, ``convert``, ``export``), a robot TOML (``collect --robot``), a VR pose file and a
kinesthetic CSV (``collect --source vr|kinesthetic``), a run directory (``eval``; its
``train_state.pt``: ``train --resume``), a LeRobot folder and a robomimic HDF5 file (``import``).

Invariant of every case: exit != 0 (or exit 0 where the corruption may leave valid input, which
``fuzz_cases`` documents per corruption), exactly one line on stderr, ``error: <file>: <problem>``
(never a traceback, never an unexpected exception), and not one byte of the source (or of a file
outside it that a path trick points at) changed.

CI runs ``DEMO_FUZZ_CASES`` cases (default 195: every corruption three times, seeded); run more with
``DEMO_FUZZ_CASES=2000`` (and another ``DEMO_FUZZ_SEED``).
"""

from __future__ import annotations

import os
import shutil
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))
import fuzz_cases as fc  # noqa: E402

from demo.cli.main import main  # noqa: E402

CASES = int(os.environ.get("DEMO_FUZZ_CASES", str(3 * len(fc.pairs()))))
SEED = int(os.environ.get("DEMO_FUZZ_SEED", "0"))


@pytest.fixture(scope="module")
def sources(tmp_path_factory: pytest.TempPathFactory, torch_one_thread) -> dict[str, Path]:
    return fc.build_sources(tmp_path_factory.mktemp("fuzz") / "sources", main)


@pytest.mark.parametrize("source", fc.SOURCES, ids=lambda s: s.name)
def test_pristine_sources_pass(source: fc.Source, sources: dict[str, Path], tmp_path: Path,
                               capfd: pytest.CaptureFixture[str]) -> None:
    """Every command succeeds on its uncorrupted source, so a refused corruption is refused for it."""
    for name in source.commands:
        work = tmp_path / name.replace(" ", "_")
        work.mkdir()
        case = fc.Case(0, source, fc.Corruption("none", lambda root, rng: "nothing"), name, 0)
        outcome = fc.run_case(case, sources, work, main, lambda: tuple(capfd.readouterr()))
        assert outcome.rc == 0 and "Traceback" not in outcome.stderr, (name, outcome.stderr[-2000:])
        assert outcome.changed == [] or source.name == "train_state", outcome.changed


def test_every_corruption_runs_in_ci() -> None:
    assert CASES >= len(fc.pairs())
    assert {(c.source.name, c.corruption.name) for c in fc.cases(CASES, SEED)} == \
        {(s.name, c.name) for s, c in fc.pairs()}


# The first pass tries every corruption once; the repeats (other seeds and commands) are slow.
@pytest.mark.parametrize("case", [c if c.index < len(fc.pairs()) else pytest.param(c, marks=pytest.mark.slow)
                                  for c in fc.cases(CASES, SEED)], ids=lambda c: c.id)
def test_corruption(case: fc.Case, sources: dict[str, Path], tmp_path: Path, capfd: pytest.CaptureFixture[str]) -> None:
    outcome = fc.run_case(case, sources, tmp_path, main, lambda: tuple(capfd.readouterr()))
    found = fc.problems(case, outcome)
    assert found == [], f"{outcome.did}; rc {outcome.rc}; stderr: {outcome.stderr[-1500:]}"
    shutil.rmtree(tmp_path, ignore_errors=True)  # thousands of cases: keep the disk use flat
