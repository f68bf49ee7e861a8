"""Layout rules: the library core loads no plotting, table or progress-bar library, and no module imports another
module's private (underscore) names."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.unit


SRC = Path(__file__).resolve().parents[1] / "src" / "swarmloc"
HEAVY = ("matplotlib", "pandas", "rich")

SCRIPT = """
import sys
import numpy as np
import swarmloc
from swarmloc import ESTIMATORS, make_team, run, GroupGaussian, SE2, UnicycleNoise, Odometry, Detection
from swarmloc.kernels import cartesian, ci, group
from swarmloc.messages import BeliefQuery
assert not [m for m in {heavy} if m in sys.modules], "after import swarmloc"
init = {{r: GroupGaussian(SE2, SE2.from_xytheta([r, 0.0, 0.0]), 1e-2 * np.eye(3)) for r in (0, 1)}}
events = [Odometry(0, 0.0, 1.0, 0.5, 0.1), Odometry(1, 0.0, 1.0, 0.5, 0.1),
          Detection(0, 1.0, "pose", np.array([1.0, 0.0, 0.0]), 1e-3 * np.eye(3), target=1),
          Detection(1, 1.0, "range_bearing", np.array([1.0, 3.1]), 1e-3 * np.eye(2), target=0),
          Detection(0, 1.0, "range_bearing", np.array([2.0, 0.5]), 1e-3 * np.eye(2), target=7, target_is_robot=False)]
for name in ESTIMATORS:
    kw = {{"noise": UnicycleNoise()}}
    if name != "dr":
        kw.update(landmarks={{7: (2.0, 1.0, 0.1, 0.1)}}, gate=0.99)
    nodes = make_team(name, init, **kw)
    res = run(nodes, events, record_times=[0.5, 1.0])
    assert res.stats["detections"] == 3 and res.accounted(), (name, res.stats)
    for n in nodes:
        n.step(BeliefQuery(sender=5, receiver=n.robots[0], stamp=1.0))
loaded = [m for m in {heavy} if m in sys.modules]
assert not loaded, loaded
print("ok")
"""


def test_core_imports_no_plotting_tables_or_progress_bars():
    """In a fresh interpreter: import swarmloc, build and step every node (odometry, detections of robots and of a
    landmark, a neighbour's query), record: matplotlib, pandas and rich are never loaded."""
    out = subprocess.run([sys.executable, "-c", SCRIPT.format(heavy=HEAVY)], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "ok"


def _private_imports(path: Path, root: Path = SRC.parent) -> list[str]:
    """Imports of another module's underscore names, and of a private module from outside its own package.

    ``from swarmloc.lie import _series`` inside ``swarmloc/lie/`` is a package using its own private module: allowed.
    Dunder names (``__version__``) are public. ``root`` is the folder that holds the ``swarmloc`` package.
    """
    tree = ast.parse(path.read_text(), filename=str(path))
    rel = path.relative_to(root).with_suffix("")
    module = ".".join(rel.parts[:-1] if rel.name == "__init__" else rel.parts)
    package = module if rel.name == "__init__" else module.rsplit(".", 1)[0]

    def private(name: str) -> bool:
        return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))

    def module_ok(target: str) -> bool:
        parts = target.split(".")
        return all(not private(p) or ".".join(parts[:i]) == package for i, p in enumerate(parts))

    bad = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("swarmloc"):
            target = node.module
            if not module_ok(target):
                bad.append(f"{path.name}:{node.lineno} imports from private module {target}")
            for alias in node.names:
                here = root / target.replace(".", "/")
                own_module = target == package and (here / f"{alias.name}.py").is_file()
                if private(alias.name) and not own_module:
                    bad.append(f"{path.name}:{node.lineno} imports {alias.name} from {target}")
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.startswith("swarmloc") and not module_ok(alias.name):
                    bad.append(f"{path.name}:{node.lineno} imports private module {alias.name}")
    return bad


def test_no_module_imports_another_modules_private_names():
    """In swarmloc and in the research studies' package beside it (``studies/src``)."""
    files = sorted(SRC.rglob("*.py"))
    studies = SRC.parents[1] / "studies" / "src"
    study_files = sorted(studies.rglob("*.py"))
    assert len(files) > 30 and len(study_files) > 10
    bad = [b for f in files for b in _private_imports(f)]
    bad += [b for f in study_files for b in _private_imports(f, root=studies)]
    assert bad == [], "\n".join(bad)


def test_the_private_import_check_catches_violations(tmp_path: Path):
    """The rule above is not vacuous: it flags both kinds of violation, and lets a package use its own private
    module. The probe package is built under tmp_path; nothing is written into src/."""
    for sub in ("estimators", "lie"):
        (tmp_path / "swarmloc" / sub).mkdir(parents=True)
    (tmp_path / "swarmloc" / "lie" / "_series.py").write_text("def sinc(x):\n    return x\n")
    fake = tmp_path / "swarmloc" / "estimators" / "probe.py"
    fake.write_text("from swarmloc.kernels.group import _bvec\nfrom swarmloc.lie._series import sinc\n")
    found = _private_imports(fake, root=tmp_path)
    assert len(found) == 2 and any("_bvec" in b for b in found) and any("lie._series" in b for b in found), found
    own = tmp_path / "swarmloc" / "lie" / "probe.py"
    own.write_text("from swarmloc.lie import _series\nfrom swarmloc.lie._series import sinc\n")
    assert _private_imports(own, root=tmp_path) == []


def test_one_meaning_of_estimators():
    """``ESTIMATORS`` is the registry of node classes and nothing else."""
    hits = []
    for f in SRC.rglob("*.py"):
        for node in ast.walk(ast.parse(f.read_text())):
            if isinstance(node, ast.Assign | ast.AnnAssign):
                targets = node.targets if isinstance(node, ast.Assign) else [node.target]
                if any(isinstance(t, ast.Name) and t.id == "ESTIMATORS" for t in targets):
                    hits.append(f.relative_to(SRC).as_posix())
    assert hits == ["estimators/__init__.py"], hits


def test_the_command_line_starts_without_the_numerical_core():
    """In a fresh interpreter, ``import swarmloc.cli`` (every command's parser) loads no other part of swarmloc and
    neither numpy nor scipy: ``swarmloc --help`` answers at once, and a node started with ``--parent-pid`` arms its
    lifeline before its heavy imports (a launcher killed while it starts must not leave it running). The public
    names still come with ``import swarmloc``, each from the subpackage that defines it."""
    code = ("import sys, swarmloc.cli\n"
            "print(sorted(m for m in sys.modules if m.partition('.')[0] in ('numpy', 'scipy', 'msgspec', 'zenoh')\n"
            "             or m.startswith('swarmloc.') and not m.startswith('swarmloc.cli')))")  # fmt: skip
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"
    import swarmloc

    stub = ast.parse((SRC / "__init__.pyi").read_text())
    home = {a.name: f"swarmloc.{n.module}" for n in stub.body if isinstance(n, ast.ImportFrom) for a in n.names}
    assert sorted(home) == sorted(swarmloc.__all__)
    for name in swarmloc.__all__:
        assert getattr(swarmloc, name) is getattr(sys.modules[home[name]], name), name
        assert name in dir(swarmloc)
