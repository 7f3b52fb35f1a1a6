"""docs/LAYOUT.md's rule between the two folders outside the product: tests and benchmarks each use the
product only, never each other (a test of a benchmark runs it as `python -m bench.NAME`)."""

import re
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def imports_of(folder: str, other: str) -> list[str]:
    """file:line of every import of package `other` in the Python files under `folder`."""
    pattern = re.compile(rf"^\s*(from|import)\s+{other}(\.|\s)", re.MULTILINE)
    return [f"{path.relative_to(REPO)}:{text.count(chr(10), 0, m.start()) + 1}"
            for path in sorted((REPO / folder).rglob("*.py"))
            for text in [path.read_text()] for m in pattern.finditer(text)]


def test_tests_and_benchmarks_do_not_import_each_other():
    assert imports_of("tests", "bench") == []
    assert imports_of("bench", "tests") == []
