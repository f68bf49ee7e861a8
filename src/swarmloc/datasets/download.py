"""Download the UTIAS MRCLAM datasets (Leung, Halpern, Barfoot and Liu 2011) from their public home, checked.

The dataset's page, ``http://asrl.utias.utoronto.ca/datasets/mrclam/``, links one zip archive per dataset, served as
``MRCLAM<N>.zip`` (N = 1..9) from :data:`DEFAULT_URL`; each holds a folder ``MRCLAM_Dataset<N>`` (dataset 4's is
named ``MRSLAM_Dataset4``) of 17 text files (:data:`FILES`). Another host (a mirror, or a test's server) is given
with ``base_url`` or the environment variable :data:`URL_ENV`.

For each dataset :func:`fetch_mrclam`

1. downloads the archive to ``DEST/.MRCLAM<N>.zip.part``; a ``.part`` left by an interrupted run is resumed where
   the server supports it (an HTTP range request; otherwise it starts over);
2. reads the archive's 17 files (nothing else; each at most :data:`MAX_FILE` bytes, the archive at most
   :data:`MAX_ARCHIVE`), *normalises* their text (:func:`normalise`: line endings LF, blanks at the ends of lines
   and blank lines at the end removed, values unchanged: as the reference copy the table was made from) and checks
   the sha256 of each against :data:`~swarmloc.datasets.mrclam_sha256.SHA256`. A file without an entry (dataset 7,
   most ``Robot<N>_Groundtruth.dat``) is counted *unverified*, never silently; one that differs fails the dataset;
3. writes the normalised files to ``DEST/.MRCLAM_Dataset<N>.partial``, then renames that folder to
   ``DEST/MRCLAM_Dataset<N>`` and removes the archive: a dataset folder is complete and checked, or not there.

A dataset folder already there whose files are all present and none differs is kept as it is (not downloaded).
"""

from __future__ import annotations

import hashlib
import os
import re
import shutil
import urllib.error
import urllib.request
import zipfile
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath

from swarmloc.datasets.mrclam_sha256 import SHA256

__all__ = [
    "DATASETS",
    "DEFAULT_URL",
    "FILES",
    "ChecksumError",
    "DownloadError",
    "Fetched",
    "archive_url",
    "check_folder",
    "fetch_mrclam",
    "normalise",
]

DEFAULT_URL = "ftp://asrl3.utias.utoronto.ca/MRCLAM/"
"""Where the dataset's page points its downloads: ``MRCLAM<N>.zip`` under it."""
URL_ENV = "SWARMLOC_MRCLAM_URL"
"""Environment variable naming another base URL (a mirror)."""
DATASETS = tuple(range(1, 10))
FILES = (
    "Barcodes.dat",
    "Landmark_Groundtruth.dat",
    *(f"Robot{r}_{kind}.dat" for r in range(1, 6) for kind in ("Groundtruth", "Measurement", "Odometry")),
)
"""The 17 files of every dataset."""
MAX_ARCHIVE = 200 * 2**20
"""[bytes] Largest archive taken (the real ones are about 6 to 11 MB)."""
MAX_FILE = 100 * 2**20
"""[bytes] Largest file taken from an archive (the largest real one is about 10 MB)."""
MAX_MEMBERS = 256
"""Most entries an archive may list."""
CHUNK = 1 << 16
TIMEOUT = 60.0
"""[s] Wait at most this long for the server to answer or send more."""

Progress = Callable[[int, int | None], None]
"""``progress(bytes received, bytes in all or None)`` while an archive downloads."""


class DownloadError(Exception):
    """The archive could not be had (no network, the server refused, an interrupted or malformed download)."""


class ChecksumError(Exception):
    """A file of the archive differs from the known one (after normalisation); ``problems`` lists each."""

    def __init__(self, message: str, problems: list[str]) -> None:
        super().__init__(message)
        self.problems = problems


@dataclass
class Fetched:
    """One dataset: its folder, the files whose sha256 matched, those with no known sha256, and whether it was
    already there (not downloaded)."""

    dataset: int
    folder: Path
    verified: list[str] = field(default_factory=list)
    unverified: list[str] = field(default_factory=list)
    kept: bool = False


def normalise(data: bytes) -> bytes:
    """The text as the reference copy holds it: line endings LF, blanks (spaces, tabs) at the ends of lines and
    blank lines at the end of the file removed, one final LF. Values are not touched."""
    text = data.replace(b"\r\n", b"\n").replace(b"\r", b"\n")
    lines = [re.sub(rb"[ \t]+$", b"", line) for line in text.split(b"\n")]
    return b"\n".join(lines).rstrip(b"\n") + b"\n"


def archive_url(base: str, dataset: int) -> str:
    """``<base>/MRCLAM<dataset>.zip``."""
    return f"{base.rstrip('/')}/MRCLAM{int(dataset)}.zip"


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _judge(dataset: int, name: str, data: bytes, out: Fetched, problems: list[str]) -> None:
    """File ``name`` (normalised ``data``) of ``dataset`` into ``out``'s verified or unverified, or a problem."""
    want = SHA256.get((dataset, name))
    if want is None:
        out.unverified.append(name)
    elif _sha(data) == want:
        out.verified.append(name)
    else:
        problems.append(f"dataset {dataset}: {name} differs from the known file (sha256 of its normalised text "
                        f"{_sha(data)[:16]}..., expected {want[:16]}...)")  # fmt: skip


def check_folder(folder: str | os.PathLike[str], dataset: int) -> tuple[Fetched, list[str]]:
    """Check a dataset folder already there: ``(what matched and what has no checksum, problems)``; a problem is a
    missing file or one that differs from the known file (its text normalised as :func:`normalise`)."""
    folder = Path(folder)
    out, problems = Fetched(dataset, folder, kept=True), []
    for name in FILES:
        f = folder / name
        if not f.is_file():
            problems.append(f"dataset {dataset}: {name} is missing")
            continue
        _judge(dataset, name, normalise(f.read_bytes()), out, problems)
    return out, problems


def fetch_mrclam(
    dest: str | os.PathLike[str],
    datasets: Iterable[int] = DATASETS,
    base_url: str | None = None,
    progress: Callable[[int], Progress] | None = None,
    timeout: float = TIMEOUT,
    env: Mapping[str, str] = os.environ,
) -> list[Fetched]:
    """Download, check and unpack ``datasets`` into ``dest`` (module docstring); returns one :class:`Fetched` per
    dataset. ``base_url``: default ``env[URL_ENV]``, else :data:`DEFAULT_URL`. ``progress(dataset)`` gives the
    :data:`Progress` callback of one dataset's download. Raises :class:`DownloadError` (the network, the server, a
    malformed archive) or :class:`ChecksumError` (a file differs); what was done before stays done."""
    numbers = sorted(set(int(n) for n in datasets))
    bad = [n for n in numbers if n not in DATASETS]
    if bad or not numbers:
        raise ValueError(f"datasets must be among {list(DATASETS)}, got {bad or 'none'}")
    base = base_url or env.get(URL_ENV) or DEFAULT_URL
    dest = Path(dest).expanduser()
    dest.mkdir(parents=True, exist_ok=True)
    done = []
    for n in numbers:
        folder = dest / f"MRCLAM_Dataset{n}"
        if folder.is_dir():
            kept, problems = check_folder(folder, n)
            if not problems:
                done.append(kept)
                continue
        part = dest / f".MRCLAM{n}.zip.part"
        _download(archive_url(base, n), part, progress(n) if progress else None, timeout)
        done.append(_unpack(part, n, folder))
        part.unlink()
    return done


def _download(url: str, part: Path, progress: Progress | None, timeout: float) -> None:
    """``url`` into ``part``, resuming a ``part`` already there where the server takes a range request."""
    have = part.stat().st_size if part.is_file() else 0
    headers = {"Range": f"bytes={have}-"} if have and url.startswith(("http://", "https://")) else {}
    try:
        resp = urllib.request.urlopen(urllib.request.Request(url, headers=headers), timeout=timeout)
    except urllib.error.HTTPError as exc:
        if exc.code == 416 and have:  # nothing past what is there: the archive is complete
            return
        raise DownloadError(f"{url}: the server answered {exc.code} {exc.reason}") from None
    except (urllib.error.URLError, OSError) as exc:
        why = getattr(exc, "reason", None) or exc
        raise DownloadError(f"cannot reach {url} ({why}): no network? Give another host with --url "
                            f"(or {URL_ENV})") from None  # fmt: skip
    with resp:
        if have and getattr(resp, "status", 200) != 206:
            have = 0  # the server sends the whole archive again
        length = resp.headers.get("Content-Length")
        size = int(length) if length is not None and length.isdigit() else None
        total = None if size is None else have + size
        if total is not None and total > MAX_ARCHIVE:
            raise DownloadError(f"{url}: {total} bytes, more than an MRCLAM archive can be ({MAX_ARCHIVE})")
        got = have
        try:
            with open(part, "ab" if have else "wb") as f:
                while chunk := resp.read(CHUNK):
                    got += len(chunk)
                    if got > MAX_ARCHIVE:
                        raise DownloadError(f"{url}: more than {MAX_ARCHIVE} bytes, more than an MRCLAM archive")
                    f.write(chunk)
                    if progress is not None:
                        progress(got, total)
        except OSError as exc:
            raise DownloadError(f"{url}: interrupted after {got} bytes ({exc}); run again to resume") from None
    if total is not None and got != total:
        raise DownloadError(f"{url}: the connection closed after {got} of {total} bytes; run again to resume")


def _members(zf: zipfile.ZipFile, dataset: int) -> dict[str, zipfile.ZipInfo]:
    """The archive's entry of each of :data:`FILES` (by its base name; anything else is left alone)."""
    infos = zf.infolist()
    if len(infos) > MAX_MEMBERS:
        raise DownloadError(f"dataset {dataset}: the archive lists {len(infos)} entries, not an MRCLAM archive")
    found: dict[str, zipfile.ZipInfo] = {}
    for info in infos:
        name = PurePosixPath(info.filename.replace("\\", "/")).name
        if info.is_dir() or name not in FILES:
            continue
        if name in found:
            raise DownloadError(f"dataset {dataset}: the archive holds {name} twice")
        if info.file_size > MAX_FILE:
            raise DownloadError(f"dataset {dataset}: {name} is {info.file_size} bytes, more than {MAX_FILE}")
        found[name] = info
    missing = [f for f in FILES if f not in found]
    if missing:
        raise DownloadError(f"dataset {dataset}: the archive lacks {', '.join(missing)}")
    return found


def _unpack(part: Path, dataset: int, folder: Path) -> Fetched:
    """Check the archive ``part``'s files and move them, normalised, into ``folder`` (module docstring, 2-3)."""
    try:
        zf = zipfile.ZipFile(part)
    except (zipfile.BadZipFile, OSError) as exc:
        part.unlink(missing_ok=True)
        raise DownloadError(f"dataset {dataset}: not a zip archive ({exc}); removed, run again") from None
    out = Fetched(dataset, folder)
    problems: list[str] = []
    tmp = folder.with_name(f".{folder.name}.partial")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    try:
        with zf:
            for name, info in _members(zf, dataset).items():
                with zf.open(info) as src:
                    data = src.read(MAX_FILE + 1)
                if len(data) > MAX_FILE:
                    raise DownloadError(f"dataset {dataset}: {name} unpacks to more than {MAX_FILE} bytes")
                text = normalise(data)
                _judge(dataset, name, text, out, problems)
                (tmp / name).write_bytes(text)
    except (zipfile.BadZipFile, OSError, EOFError) as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        part.unlink(missing_ok=True)
        raise DownloadError(f"dataset {dataset}: a damaged archive ({exc}); removed, run again") from None
    except DownloadError:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    if problems:
        shutil.rmtree(tmp, ignore_errors=True)
        raise ChecksumError(f"dataset {dataset}: {len(problems)} file(s) differ from the known ones; nothing "
                            f"written (the archive stays at {part})", problems)  # fmt: skip
    if folder.exists():  # an incomplete or different folder of an earlier run: replaced
        shutil.rmtree(folder)
    os.replace(tmp, folder)
    out.verified.sort(key=FILES.index)
    out.unverified.sort(key=FILES.index)
    return out
