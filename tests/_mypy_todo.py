"""The type checker's to-do list in ``pyproject.toml``: the error codes mypy still reports, per module.

Between the ``# mypy to-do: begin`` and ``# mypy to-do: end`` markers of ``[tool.mypy]``, each module that mypy
still finds errors in is listed with the error codes it reports there, disabled in that module only. This script
runs mypy without that block and compares what it reports with the list::

    python tests/_mypy_todo.py            # check: fails if a module or code is missing from the list, or listed
                                          # but clean (take it off); prints the difference
    python tests/_mypy_todo.py --write    # rewrite the block from what mypy reports now (after a merge)

Run from the repository root with the virtual environment active (mypy from the dev extra).
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
import tomllib
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BEGIN, END = "# mypy to-do: begin", "# mypy to-do: end"
HEADER = (
    "# the type checker's to-do: the error codes mypy still reports in these modules, disabled there and only there\n"
    "# (fix a module's errors, then take it off this list; the list only shrinks; python tests/_mypy_todo.py checks\n"
    "# it against mypy, --write rewrites it)\n"
)
ERROR = re.compile(r"^src/(swarmloc/.+?)\.py:\d+: error: .*\[([a-z-]+)\]$")


def split(text: str) -> tuple[str, str, str]:
    """``pyproject.toml``'s text before the block, the block (markers excluded), and from the end marker on."""
    a, b = text.index(BEGIN), text.index(END)
    return text[:a], text[a + len(BEGIN) : b], text[b:]


def listed(block: str) -> dict[str, set[str]]:
    """``module -> codes`` of the block."""
    out: dict[str, set[str]] = defaultdict(set)
    for o in tomllib.loads(block).get("tool", {}).get("mypy", {}).get("overrides", []):
        for m in o["module"]:
            out[m] |= set(o["disable_error_code"])
    return dict(out)


def reported(pyproject: Path) -> dict[str, set[str]]:
    """``module -> codes`` mypy reports with the block left out of ``pyproject``'s configuration."""
    before, _, after = split(pyproject.read_text())
    config = pyproject.with_name(".mypy_todo.toml")
    config.write_text(before + after)
    try:
        run = subprocess.run([sys.executable, "-m", "mypy", "--config-file", str(config)], cwd=ROOT,
                             capture_output=True, text=True)  # fmt: skip
    finally:
        config.unlink()
    if run.returncode not in (0, 1):
        sys.exit(f"mypy failed to run:\n{run.stdout}{run.stderr}")
    out: dict[str, set[str]] = defaultdict(set)
    for line in run.stdout.splitlines():
        m = ERROR.match(line)
        if m:
            out[m.group(1).replace("/", ".").removesuffix(".__init__")].add(m.group(2))
    return dict(out)


def render(todo: dict[str, set[str]]) -> str:
    """The block for ``todo``: one override per set of codes, its modules sorted."""
    groups: dict[tuple[str, ...], list[str]] = defaultdict(list)
    for mod, codes in todo.items():
        groups[tuple(sorted(codes))].append(mod)
    parts = []
    for codes, mods in sorted(groups.items(), key=lambda kv: min(kv[1])):
        names = "".join(f'    "{m}",\n' for m in sorted(mods))
        parts.append(
            f"[[tool.mypy.overrides]]\nmodule = [\n{names}]\ndisable_error_code = {list(codes)}\n".replace("'", '"')
        )
    return "\n" + HEADER + "\n" + "\n".join(parts)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--write", action="store_true", help="rewrite the block from what mypy reports now")
    args = ap.parse_args()
    pyproject = ROOT / "pyproject.toml"
    now = reported(pyproject)
    if args.write:
        before, _, after = split(pyproject.read_text())
        pyproject.write_text(before + BEGIN + render(now) + after)
        print(f"{len(now)} modules, {sum(map(len, now.values()))} module-codes on the list")
        return 0
    old = listed(split(pyproject.read_text())[1])
    missing = {m: sorted(c - old.get(m, set())) for m, c in now.items() if c - old.get(m, set())}
    clean = {m: sorted(c - now.get(m, set())) for m, c in old.items() if c - now.get(m, set())}
    if missing:
        print(f"reported by mypy, not on the list (fix them): {missing}")
    if clean:
        print(f"on the list, no longer reported (take them off, or --write): {clean}")
    if not missing and not clean:
        print(f"the list is current: {len(old)} modules, {sum(map(len, old.values()))} module-codes")
    return 1 if missing or clean else 0


if __name__ == "__main__":
    sys.exit(main())
