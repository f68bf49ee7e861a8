"""What the experiments write: a figure as a file, a summary as its JSON and Markdown pair."""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any


def save_figure(fig: Any, path: str | os.PathLike[str], dpi: int = 110) -> str:
    """Lay out ``fig`` (a matplotlib figure), write it to ``path`` at ``dpi`` and close it; returns the path."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return str(path)


def write_summary(out_dir: str | os.PathLike[str], stem: str, summary: Any, markdown: str, indent: int = 2,
                  default: Callable[[Any], Any] | None = None) -> Path:  # fmt: skip
    """``summary`` as ``<stem>.json`` (indented by ``indent``; ``default``: ``json.dumps``' for what JSON cannot
    hold) and ``markdown`` as ``<stem>.md`` in ``out_dir`` (made if missing); returns the folder."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{stem}.json").write_text(json.dumps(summary, indent=indent, default=default))
    (out / f"{stem}.md").write_text(markdown)
    return out
