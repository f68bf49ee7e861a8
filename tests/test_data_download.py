"""``swarmloc data mrclam DIR``: the download of the UTIAS MRCLAM datasets, against a local HTTP server on 127.0.0.1
that serves archives built here from the reference copy (the tests never download; this machine may not reach the
dataset's host). Checked: the sha256 table against the copy, normalisation of the text, files without a checksum
counted unverified, a changed file refused, an interrupted download resumed, one clear line without a network."""

from __future__ import annotations

import hashlib
import http.server
import io
import threading
import zipfile
from collections.abc import Iterator
from pathlib import Path

import pytest

from swarmloc.cli import main
from swarmloc.datasets.download import FILES, normalise
from swarmloc.datasets.mrclam_sha256 import SHA256
from swarmloc.net.transport import free_ports

pytestmark = pytest.mark.data


def test_the_table_is_the_reference_copy(mrclam_root: Path):
    """Every file of the copy has its entry, the sha256 of its normalised text (the copy is normalised already),
    and every entry its file; the files the copy lacks (MISSING.txt) have none."""
    files = {(int(f.parent.name.removeprefix("MRCLAM_Dataset")), f.name): f
             for f in mrclam_root.glob("MRCLAM_Dataset*/*.dat")}  # fmt: skip
    assert set(files) == set(SHA256) and len(SHA256) == 90
    for key, f in files.items():
        data = f.read_bytes()
        assert normalise(data) == data, f
        assert hashlib.sha256(data).hexdigest() == SHA256[key], f
    missing = (mrclam_root / "MISSING.txt").read_text().split()
    for m in missing:
        folder, name = m.split("/")
        assert (int(folder.removeprefix("MRCLAM_Dataset")), name) not in SHA256


def test_normalise_takes_crlf_and_trailing_blanks_and_keeps_values():
    assert normalise(b"# h \r\n1.5\t2 \r\n3\t4\r\n\r\n") == b"# h\n1.5\t2\n3\t4\n"
    assert normalise(b"1 2\r3 4") == b"1 2\n3 4\n"


# ------------------------------------------------------------------------------------------------ a local host
class _Host(http.server.BaseHTTPRequestHandler):
    """Serves ``files`` (path -> bytes) with ``Range: bytes=N-``; ``cut``: the next answer stops after that many
    bytes (a dropped connection); ``seen``: ``(path, Range header)`` of every request."""

    files: dict[str, bytes] = {}
    cut: int | None = None
    seen: list[tuple[str, str | None]] = []

    def do_GET(self) -> None:  # noqa: N802 - http.server's name
        type(self).seen.append((self.path, self.headers.get("Range")))
        data = self.files.get(self.path)
        if data is None:
            self.send_error(404)
            return
        start = 0
        rng = self.headers.get("Range")
        if rng and rng.startswith("bytes=") and rng.endswith("-"):
            start = int(rng[6:-1])
            if start >= len(data):
                self.send_error(416)
                return
            self.send_response(206)
            self.send_header("Content-Range", f"bytes {start}-{len(data) - 1}/{len(data)}")
        else:
            self.send_response(200)
        self.send_header("Content-Length", str(len(data) - start))
        self.end_headers()
        body = data[start:]
        if type(self).cut is not None:
            body, type(self).cut = body[: type(self).cut], None
        self.wfile.write(body)

    def log_message(self, *args: object) -> None:
        pass


@pytest.fixture
def host() -> Iterator[tuple[str, type[_Host]]]:
    handler = type("Host", (_Host,), {"files": {}, "cut": None, "seen": []})
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    th = threading.Thread(target=server.serve_forever, daemon=True)
    th.start()
    try:
        yield f"http://127.0.0.1:{server.server_address[1]}/MRCLAM/", handler
    finally:
        server.shutdown()
        server.server_close()
        th.join(5)


GROUNDTRUTH = [f"Robot{r}_Groundtruth.dat" for r in range(1, 6)]  # dataset 9's, not in the copy (over 4 MB)


def _archive(copy: Path, change: str | None = None) -> bytes:
    """Dataset 9 as its archive might hold it: CRLF line endings and blanks at the line ends (normalised away), the
    odd folder name of dataset 4's archive, a small stand-in for each ground truth file the copy lacks; with
    ``change``, one value of that file altered."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        for name in FILES:
            f = copy / name
            text = f.read_bytes() if f.is_file() else b"# Time [s]    x [m]    y [m]    Orientation [rad]\n1 0 0 0\n"
            if name == change:
                lines = text.split(b"\n")
                lines[10] = lines[10].replace(b"0", b"1", 1)
                text = b"\n".join(lines)
            zf.writestr(f"MRSLAM_Dataset9/{name}", text.replace(b"\n", b"  \r\n"))
        zf.writestr("MRSLAM_Dataset9/readme.txt", b"not one of the 17 files: left alone")
    return buf.getvalue()


def test_download_checks_normalises_and_unpacks_counting_the_unverified(tmp_path, mrclam_dataset, host, capsys):
    url, h = host
    copy = mrclam_dataset(9)
    h.files["/MRCLAM/MRCLAM9.zip"] = _archive(copy)
    dest = tmp_path / "data"
    assert main(["data", "mrclam", str(dest), "--datasets", "9", "--url", url, "--quiet"]) == 0
    out = capsys.readouterr().out
    folder = dest / "MRCLAM_Dataset9"
    assert f"dataset 9: {folder} (downloaded): 12 files verified, 5 unverified ({', '.join(GROUNDTRUTH)})" in out
    assert "unverified: 5 file(s) with no known checksum" in out
    assert sorted(p.name for p in folder.iterdir()) == sorted(FILES)
    for f in copy.iterdir():  # written normalised: byte for byte the reference copy
        assert (folder / f.name).read_bytes() == f.read_bytes(), f.name
    assert sorted(p.name for p in dest.iterdir()) == ["MRCLAM_Dataset9"]  # no archive, no partial folder left
    # again: kept as it is, nothing asked of the host
    assert main(["data", "mrclam", str(dest), "--datasets", "9", "--url", url, "--quiet"]) == 0
    assert f"dataset 9: {folder} (already there): 12 files verified" in capsys.readouterr().out
    assert len(h.seen) == 1


def test_an_interrupted_download_is_resumed_and_nothing_half_done_is_left(
    tmp_path, mrclam_dataset, host, capsys, terminal_progress
):
    url, h = host
    archive = _archive(mrclam_dataset(9))
    h.files["/MRCLAM/MRCLAM9.zip"] = archive
    h.cut = len(archive) // 3
    dest = tmp_path / "data"
    assert main(["data", "mrclam", str(dest), "--datasets", "9", "--url", url, "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"closed after {len(archive) // 3} of {len(archive)} bytes; run again" in err
    assert sorted(p.name for p in dest.iterdir()) == [".MRCLAM9.zip.part"]  # no dataset folder
    assert main(["data", "mrclam", str(dest), "--datasets", "9", "--url", url]) == 0
    assert "MRCLAM9.zip" in capsys.readouterr().err  # the progress bar, on stderr
    assert h.seen[-1] == ("/MRCLAM/MRCLAM9.zip", f"bytes={len(archive) // 3}-")  # resumed where it stopped
    assert sorted(p.name for p in dest.iterdir()) == ["MRCLAM_Dataset9"]


def test_a_changed_file_is_refused_and_no_dataset_written(tmp_path, mrclam_dataset, host, capsys):
    url, h = host
    h.files["/MRCLAM/MRCLAM9.zip"] = _archive(mrclam_dataset(9), change="Robot3_Measurement.dat")
    dest = tmp_path / "data"
    assert main(["data", "mrclam", str(dest), "--datasets", "9", "--url", url, "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "dataset 9: Robot3_Measurement.dat differs from the known file" in err
    assert not (dest / "MRCLAM_Dataset9").exists() and (dest / ".MRCLAM9.zip.part").is_file()


def test_no_network_is_one_clear_line_and_exit_2(tmp_path, capsys, monkeypatch):
    port = free_ports(1)[0]  # nothing listens there
    monkeypatch.setenv("SWARMLOC_MRCLAM_URL", f"http://127.0.0.1:{port}/MRCLAM/")  # the base URL from the environment
    assert main(["data", "mrclam", str(tmp_path / "d"), "--datasets", "1,2", "--quiet"]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1
    assert err.startswith(f"swarmloc data mrclam: cannot reach http://127.0.0.1:{port}/MRCLAM/MRCLAM1.zip (")
    assert "no network? Give another host with --url" in err
    assert main(["data", "mrclam", str(tmp_path / "d"), "--datasets", "0,10", "--quiet"]) == 2
    assert "datasets must be among [1, 2, 3, 4, 5, 6, 7, 8, 9]" in capsys.readouterr().err
