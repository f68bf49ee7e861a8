"""``swarmloc data mrclam DIR``: download the UTIAS MRCLAM datasets, checked (:mod:`swarmloc.datasets.download`)."""

from __future__ import annotations

import argparse
import sys

from swarmloc.cli.common import refuse


def add_parser(sub: argparse._SubParsersAction) -> None:
    """The ``data`` command: its options and help."""
    d = sub.add_parser("data", help="download public data sets: 'mrclam DIR' (the UTIAS MRCLAM datasets, checked)")
    d.add_argument("what", choices=["mrclam"], help="mrclam: the UTIAS MRCLAM datasets (Leung et al. 2011)")
    d.add_argument("dir", help="folder to put MRCLAM_Dataset<N>/ in (made if needed)")
    d.add_argument("--datasets", default=None, help="comma-separated numbers 1-9 (default: all nine)")
    d.add_argument("--url", default=None,
                   help="base URL of the MRCLAM<N>.zip archives (default: $SWARMLOC_MRCLAM_URL, else the dataset's "
                        "public home, ftp://asrl3.utias.utoronto.ca/MRCLAM/)")  # fmt: skip
    d.add_argument("--quiet", action="store_true", help="no progress bar")
    d.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Download and check the MRCLAM datasets; 0, 1 on a checksum mismatch, 2 on bad input."""
    from swarmloc.datasets.download import DATASETS, ChecksumError, DownloadError, fetch_mrclam
    from swarmloc.experiments.progress import progress_bar

    where = f"data {args.what}"
    try:
        numbers = [int(x) for x in args.datasets.split(",") if x.strip()] if args.datasets else list(DATASETS)
    except ValueError:
        return refuse(where, f"--datasets takes numbers 1-9 separated by commas, got {args.datasets!r}")
    try:
        with progress_bar(not args.quiet) as start:
            got = fetch_mrclam(args.dir, numbers, base_url=args.url,
                               progress=(lambda n: start(f"MRCLAM{n}.zip")) if start else None)  # fmt: skip
    except (DownloadError, ValueError, OSError) as exc:
        return refuse(where, exc)
    except ChecksumError as exc:
        print(f"swarmloc {where}: {exc}", file=sys.stderr)
        for p in exc.problems:
            print(f"  {p}", file=sys.stderr)
        return 1
    n_unverified = 0
    for f in got:
        how = "already there" if f.kept else "downloaded"
        line = f"dataset {f.dataset}: {f.folder} ({how}): {len(f.verified)} files verified"
        if f.unverified:
            n_unverified += len(f.unverified)
            line += f", {len(f.unverified)} unverified ({', '.join(f.unverified)})"
        print(line)
    print("verified: the sha256 of each file's text, line endings and trailing blanks normalised (as the files are "
          "written), matches swarmloc's table.")  # fmt: skip
    if n_unverified:
        print(f"unverified: {n_unverified} file(s) with no known checksum (swarmloc's table comes from a copy that "
              "lacks dataset 7 and most files over 4 MB); they were read and written, but not checked.")  # fmt: skip
    first = got[0].folder
    print(f"next: swarmloc evaluate mrclam {first}; the tests read them with SWARMLOC_MRCLAM={first.parent}")
    return 0
