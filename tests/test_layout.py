"""The test tree: pytest imports test modules outside packages by their file name, so two such modules with
the same name in different folders break collection of the whole run (CI failed on that twice)."""

from collections import Counter
from pathlib import Path

TESTS = Path(__file__).resolve().parent


def test_test_module_names_are_unique_outside_packages():
    loose = [p for p in TESTS.rglob("test_*.py") if not (p.parent / "__init__.py").exists()]
    repeated = [name for name, n in Counter(p.name for p in loose).items() if n > 1]
    assert not repeated, f"rename one of each: {repeated}"
