"""Tests mirror the code tree: tests/<package path>/test_*.py tests that package (docs/architecture.md)."""

from __future__ import annotations

from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
TESTS = REPO / "tests"
# Tests of the whole chain or of repository files rather than of one package live at tests/ itself.
WHOLE_REPO_TESTS = {"test_faults.py", "test_stress_fast.py", "test_stress_slow.py", "test_makefile.py",
                    "test_layout.py", "test_example_two_pass.py"}


def test_every_test_file_sits_under_the_package_it_tests():
    misplaced = []
    for test in sorted(TESTS.rglob("test_*.py")):
        folder = test.parent.relative_to(TESTS)
        if folder == Path("."):
            if test.name not in WHOLE_REPO_TESTS:
                misplaced.append(f"{test.relative_to(REPO)}: move it under tests/<package it tests>/")
            continue
        package = REPO / folder
        if not (package / "__init__.py").is_file():
            misplaced.append(f"{test.relative_to(REPO)}: {folder.as_posix()}/ is not a package of the code tree")
            continue
        # The test must name its package (an import, or the path of a script it runs).
        text = test.read_text()
        if folder.as_posix().replace("/", ".") not in text and folder.as_posix() not in text:
            misplaced.append(f"{test.relative_to(REPO)}: never names {folder.as_posix().replace('/', '.')}")
    assert not misplaced, "\n".join(misplaced)


def test_shared_fixtures_are_not_test_modules():
    support = TESTS / "support"
    assert not list(support.glob("test_*.py")), "tests/support/ holds fixtures only"
    assert not [p for p in TESTS.glob("*.py") if p.name not in WHOLE_REPO_TESTS | {"conftest.py"}], \
        "shared fixtures belong in tests/support/"
