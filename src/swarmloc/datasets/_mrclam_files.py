"""The file readers of the MRCLAM loader (:mod:`swarmloc.datasets.mrclam`, whose docstring describes the files and the
two corrections made on loading): the folder and its robots' files, the barcodes, the landmark map, a file's timed
rows, the yaw-rate clip, the measurements by subject, and the robots' common time span. Every problem raises
:class:`MRCLAMError`."""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from swarmloc.datasets.tables import file_label, integer_column, line_of_row, read_table, sort_by_time

ROBOT_SUBJECTS: tuple[int, ...] = (1, 2, 3, 4, 5)
"""Subject ids of the robots in every MRCLAM dataset (landmarks are 6-20)."""

MAX_YAW_RATE = 0.6
"""[rad/s] the yaw rate the MRCLAM robots executed at most: commanded yaw rates beyond it are clipped on loading
(dataset 9's turn commands of 0.902 and 1.003 rad/s were executed at 0.60 rad/s; module docstring)."""

BARCODE_SWAPS: tuple[tuple[int, int, tuple[float, float], tuple[float, float]], ...] = (
    (18, 61, (3.15071999, 2.38294871), (0.03596156, -2.84396626)),
)
"""Known barcode swaps ``(barcode a, barcode b, map xy [m] of a's subject, map xy [m] of b's subject)``: when
``Barcodes.dat`` and ``Landmark_Groundtruth.dat`` hold exactly these (to 1 mm), the subjects of barcodes ``a`` and
``b`` are exchanged (dataset 1, landmarks 11 and 17; module docstring)."""

_KINDS = ("odometry", "measurements", "truth")
_FILE_SUFFIX = {"odometry": "Odometry", "measurements": "Measurement", "truth": "Groundtruth"}


class MRCLAMError(ValueError):
    """A problem with MRCLAM data: missing folder or file, malformed line, no usable time span, no ground truth."""


def swap_barcodes(
    barcode_to_subject: dict[int, int], landmarks: dict[int, tuple[float, float, float, float]], notes: list[str]
) -> None:
    """Apply :data:`BARCODE_SWAPS` in place where the files hold exactly the known defect; note each swap."""
    for a, b, xy_a, xy_b in BARCODE_SWAPS:
        sa, sb = barcode_to_subject.get(a), barcode_to_subject.get(b)
        if sa is None or sb is None or sa not in landmarks or sb not in landmarks:
            continue
        if np.allclose(landmarks[sa][:2], xy_a, atol=1e-3) and np.allclose(landmarks[sb][:2], xy_b, atol=1e-3):
            barcode_to_subject[a], barcode_to_subject[b] = sb, sa
            notes.append(
                f"barcodes {a} and {b} swapped (subjects {sa} and {sb}): the readings of each fit the other's map "
                "position (known defect of MRCLAM dataset 1)"
            )


def available(folder: Path) -> str:
    try:
        names = sorted(p.name for p in folder.iterdir())
    except OSError:
        return "unreadable"
    return ", ".join(names) if names else "nothing"


def require_kinds(require: Iterable[str], require_truth: bool) -> set[str]:
    if isinstance(require, str):
        require = (require,)
    kinds = set(require)
    unknown = kinds - set(_KINDS)
    if unknown:
        raise ValueError(f"require: unknown kind(s) {sorted(unknown)}; choose from {list(_KINDS)}")
    if require_truth:
        kinds.add("truth")
    return kinds


def folder(path: str | os.PathLike[str]) -> Path:
    """The dataset folder of ``path``, after checking it is one and holds ``Barcodes.dat`` and
    ``Landmark_Groundtruth.dat`` (:class:`MRCLAMError` naming what is there otherwise)."""
    folder = Path(path).expanduser()
    if not folder.is_dir():
        parent = folder.parent
        if folder.exists():
            raise MRCLAMError(f"MRCLAM path {folder} is not a folder")
        if parent.is_dir():
            sibs = sorted(p.name for p in parent.iterdir() if p.is_dir() and p.name.startswith("MRCLAM"))
            avail = f"available MRCLAM folders in {parent}: {', '.join(sibs) if sibs else 'none'}"
        else:
            avail = f"parent folder {parent} does not exist either"
        raise MRCLAMError(f"MRCLAM folder not found: {folder} ({avail})")
    for fname in ("Barcodes.dat", "Landmark_Groundtruth.dat"):
        if not (folder / fname).is_file():
            raise MRCLAMError(
                f"{folder.name}: required file {fname} missing in {folder} (available: {available(folder)})"
            )
    return folder


def robot_files(folder: Path) -> tuple[dict[int, dict[str, Path]], list[str]]:
    """Which per-robot files exist: robot -> kind -> path, and the names of the missing ones."""
    present: dict[int, dict[str, Path]] = {}
    missing: list[str] = []
    for r in ROBOT_SUBJECTS:
        present[r] = {}
        for kind in _KINDS:
            p = folder / f"Robot{r}_{_FILE_SUFFIX[kind]}.dat"
            if p.is_file():
                present[r][kind] = p
            else:
                missing.append(p.name)
    return present, missing


def chosen_robots(
    folder: Path, robots: Iterable[int] | None, kinds: set[str], present: dict[int, dict[str, Path]],
    missing: list[str],
) -> list[int]:  # fmt: skip
    """The robots to load (:func:`load_mrclam`'s ``robots``): every one with the ``kinds`` required, or the ones
    asked for, which must have them; :class:`MRCLAMError` saying what lacks otherwise."""
    name = folder.name

    def lacking(r: int) -> list[str]:
        return [f"Robot{r}_{_FILE_SUFFIX[k]}.dat" for k in sorted(kinds) if k not in present[r]]

    if robots is None:
        if kinds:
            chosen = [r for r in ROBOT_SUBJECTS if not lacking(r)]
        else:
            chosen = [r for r in ROBOT_SUBJECTS if present[r]]
        if not chosen:
            absent = [k for k in sorted(kinds) if all(k not in present[r] for r in ROBOT_SUBJECTS)]
            if absent:
                what = " and ".join(absent)
                patterns = ", ".join(f"Robot*_{_FILE_SUFFIX[k]}.dat" for k in absent)
                raise MRCLAMError(
                    f"{name}: {what} missing for every robot (no {patterns} in {folder}); "
                    f"available: {available(folder)}; required: {sorted(kinds)}"
                )
            raise MRCLAMError(
                f"{name}: no robot has all required files {sorted(kinds)} in {folder}; "
                f"missing: {', '.join(missing)}; available: {available(folder)}"
            )
        return chosen
    chosen = sorted({int(r) for r in robots})
    if not chosen:
        raise ValueError("robots: empty selection")
    bad_ids = [r for r in chosen if r not in ROBOT_SUBJECTS]
    if bad_ids:
        raise ValueError(f"robots: {bad_ids} are not robot subjects {list(ROBOT_SUBJECTS)}")
    for r in chosen:
        lack = lacking(r)
        if lack:
            raise MRCLAMError(
                f"{name}: robot {r} lacks required file(s) {', '.join(lack)} in {folder} "
                f"(available: {available(folder)})"
            )
        if not kinds and not present[r]:
            raise MRCLAMError(f"{name}: no files for robot {r} in {folder} (available: {available(folder)})")
    return chosen


def barcodes(bc_path: Path) -> dict[int, int]:
    """``Barcodes.dat``: barcode -> subject (one subject per barcode)."""
    bc = read_table(bc_path, 2, MRCLAMError)
    if bc.shape[0] == 0:
        raise MRCLAMError(f"{file_label(bc_path)}: no data rows")
    subjects = integer_column(bc_path, bc, 0, "subject", MRCLAMError)
    codes = integer_column(bc_path, bc, 1, "barcode", MRCLAMError)
    barcode_to_subject: dict[int, int] = {}
    for i, (s, b) in enumerate(zip(subjects.tolist(), codes.tolist(), strict=True)):
        if b in barcode_to_subject and barcode_to_subject[b] != s:
            lineno, content = line_of_row(bc_path, i)
            raise MRCLAMError(
                f"{file_label(bc_path)} line {lineno}: barcode {b} already assigned to subject {barcode_to_subject[b]}"
            )
        barcode_to_subject[b] = s
    return barcode_to_subject


def landmarks(lm_path: Path) -> dict[int, tuple[float, float, float, float]]:
    """``Landmark_Groundtruth.dat``: subject -> ``(x, y, x std, y std)`` [m]."""
    lm = read_table(lm_path, 5, MRCLAMError)
    lm_subjects = integer_column(lm_path, lm, 0, "subject", MRCLAMError)
    return {
        int(s): (float(row[1]), float(row[2]), float(row[3]), float(row[4]))
        for s, row in zip(lm_subjects.tolist(), lm, strict=True)
    }


def timed_rows(p: Path, ncols: int, notes: list[str]) -> np.ndarray:
    """A robot's odometry or ground-truth file sorted by time (a note when it was not), at least one row."""
    arr = sort_by_time(p, read_table(p, ncols, MRCLAMError), notes)
    if arr.shape[0] == 0:
        raise MRCLAMError(f"{file_label(p)}: no data rows")
    return arr


def clip_yaw_rates(p: Path, arr: np.ndarray, notes: list[str]) -> None:
    """Clip the odometry ``arr``'s yaw rates to :data:`MAX_YAW_RATE` in place, noting how many were beyond."""
    fast = np.abs(arr[:, 2]) > MAX_YAW_RATE
    if fast.any():
        arr[:, 2] = np.clip(arr[:, 2], -MAX_YAW_RATE, MAX_YAW_RATE)
        notes.append(
            f"{file_label(p)}: yaw rate of {int(fast.sum())} of {arr.shape[0]} rows clipped to "
            f"+-{MAX_YAW_RATE} rad/s (commands beyond what the robots turned)"
        )


def measurements(p: Path, barcode_to_subject: dict[int, int], skipped: dict[int, int], notes: list[str]) -> np.ndarray:
    """A robot's measurement file with barcodes mapped to subjects, sorted by time; rows of unknown barcodes are
    dropped and counted in ``skipped`` (barcode -> rows)."""
    known = np.array(sorted(barcode_to_subject), dtype=np.int64)
    mapped = np.array([barcode_to_subject[b] for b in known.tolist()], dtype=np.float64)
    arr = read_table(p, 4, MRCLAMError)
    code = integer_column(p, arr, 1, "barcode", MRCLAMError)
    if known.size:
        pos_c = np.minimum(np.searchsorted(known, code), known.size - 1)
        ok = known[pos_c] == code
    else:  # pragma: no cover - Barcodes.dat with no rows is rejected above
        pos_c, ok = np.zeros(code.size, dtype=np.int64), np.zeros(code.size, dtype=bool)
    if not ok.all():
        vals, counts = np.unique(code[~ok], return_counts=True)
        for b, n in zip(vals.tolist(), counts.tolist(), strict=True):
            skipped[b] = skipped.get(b, 0) + n
    arr = arr[ok].copy()
    arr[:, 1] = mapped[pos_c[ok]]
    return sort_by_time(p, arr, notes)


def time_span(
    folder: Path, chosen: list[int], odometry: dict[int, np.ndarray], measurements: dict[int, np.ndarray],
    truth: dict[int, np.ndarray], notes: list[str],
) -> tuple[float, float]:  # fmt: skip
    """The span ``(t_start, t_end)`` common to the robots' odometry (else the measurements' or the ground truth's),
    narrowed to the ground truth's when there is some (noted when by more than 1 s)."""
    if odometry:
        spans = [(float(a[0, 0]), float(a[-1, 0])) for a in odometry.values()]
        t_start = max(s for s, _ in spans)
        t_end = min(e for _, e in spans)
        basis = "odometry"
    else:
        ms = [a for a in measurements.values() if a.shape[0]]
        if ms:
            t_start = min(float(a[0, 0]) for a in ms)
            t_end = max(float(a[-1, 0]) for a in ms)
            basis = "measurement"
        elif truth:
            t_start = max(float(a[0, 0]) for a in truth.values())
            t_end = min(float(a[-1, 0]) for a in truth.values())
            basis = "ground-truth"
        else:
            raise MRCLAMError(f"{folder.name}: no data rows for robots {chosen} in {folder}")
    if truth:
        for r, a in truth.items():
            early, late = float(a[0, 0]) - t_start, t_end - float(a[-1, 0])
            if early > 1.0:
                notes.append(f"ground truth of robot {r} starts {early:.1f} s after the {basis} span: t_start moved")
            if late > 1.0:
                notes.append(f"ground truth of robot {r} ends {late:.1f} s before the {basis} span: t_end moved")
        t_start = max(t_start, max(float(a[0, 0]) for a in truth.values()))
        t_end = min(t_end, min(float(a[-1, 0]) for a in truth.values()))
        basis += " and ground-truth"
    if not t_end > t_start:
        raise MRCLAMError(f"{folder.name}: the {basis} time spans of robots {chosen} do not overlap")
    return t_start, t_end
