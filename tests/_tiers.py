"""The ``slow`` tier, measured: ``tests/slow_tests.txt`` lists the tests (pytest node ids) that took longer than
:data:`THRESHOLD` seconds in a measured run; ``tests/conftest.py`` marks them ``slow`` (beside those marked in their
module), so that ``python -m pytest -q -m "not slow"`` stays under 3 minutes on two cores.

Regenerate it from a run's JUnit XML (``python -m pytest -q --junitxml=run.xml``, ideally the whole suite):

    python tests/_tiers.py run.xml

Only tests that ran are judged: a test absent from the XML keeps its line.
"""

from __future__ import annotations

import sys
import xml.etree.ElementTree as ET
from pathlib import Path

HERE = Path(__file__).resolve().parent
SLOW_LIST = HERE / "slow_tests.txt"
THRESHOLD = 2.0
"""[s] A test that took longer (setup, call and teardown, on the measuring machine) is slow."""
HEADER = (
    "# Tests marked slow (tests/conftest.py): over 2 s in a measured run (python tests/_tiers.py run.xml makes this\n"
    "# list from a run's JUnit XML). One pytest node id per line.\n"
)


def node_id(classname: str, name: str) -> str:
    """``tests.test_x`` + ``test_y[p]`` -> ``tests/test_x.py::test_y[p]``."""
    return f"{classname.replace('.', '/')}.py::{name}"


def read_list(path: Path = SLOW_LIST) -> set[str]:
    """The node ids of the list (comments and blank lines skipped); empty when there is no list."""
    if not path.is_file():
        return set()
    return {s for line in path.read_text().splitlines() if (s := line.strip()) and not s.startswith("#")}


def durations(junit: Path) -> dict[str, float]:
    """Seconds per node id of a JUnit XML report."""
    root = ET.parse(junit).getroot()
    return {
        node_id(tc.get("classname", ""), tc.get("name", "")): float(tc.get("time", 0.0)) for tc in root.iter("testcase")
    }


def update(junit: Path, path: Path = SLOW_LIST, threshold: float = THRESHOLD) -> tuple[int, int]:
    """Rewrite the list from ``junit``: the tests that ran are slow when over ``threshold``; the others keep their
    line. Returns ``(slow, of them measured)``."""
    ran = durations(junit)
    keep = {t for t in read_list(path) if t not in ran}
    slow = keep | {t for t, s in ran.items() if s > threshold}
    path.write_text(HEADER + "".join(f"{t}\n" for t in sorted(slow)))
    return len(slow), len(slow) - len(keep)


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: python tests/_tiers.py run.xml")
    n, measured = update(Path(sys.argv[1]))
    print(f"{SLOW_LIST}: {n} slow tests ({measured} measured in this run)")
