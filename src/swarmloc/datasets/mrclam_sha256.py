"""sha256 of the UTIAS MRCLAM dataset files, of their *normalised* text (:func:`swarmloc.datasets.download.normalise`:
line endings LF, blanks at the ends of lines and blank lines at the end of the file removed; values unchanged).

Made from the reference copy the tests read (``shared/data/mrclam`` beside the repository; its ``PROVENANCE.tsv``
names each file's public source and the first 16 hex digits of these same hashes): the archives on the dataset's
public home could not be downloaded where this table was made, so neither their own sha256 nor that of their
files as they come is known; what is known is the content, once normalised, which is what
:func:`~swarmloc.datasets.download.fetch_mrclam` checks. The copy lacks dataset 7 and most files over 4 MB (most
``Robot<N>_Groundtruth.dat``, some odometry): those have no entry here, and a download counts them
*unverified*. ``tests/test_data_download.py`` checks every entry against the copy.

The table is data: ``mrclam_sha256.tsv`` beside this module, one file a line (dataset number, file name, sha256,
separated by tabs; ``#`` starts a comment line).
"""

from pathlib import Path

TABLE = Path(__file__).with_name("mrclam_sha256.tsv")
"""The table's file (package data)."""


def _read(path: Path) -> dict[tuple[int, str], str]:
    """``(dataset, file name) -> sha256`` of the tab-separated table at ``path``."""
    rows = [line.split("\t") for line in path.read_text(encoding="utf-8").splitlines() if not line.startswith("#")]
    return {(int(n), name): digest for n, name, digest in rows}


SHA256: dict[tuple[int, str], str] = _read(TABLE)
"""``(dataset number, file name) -> sha256`` (hex) of the file's normalised text."""
