"""The files every experiment writes beside its numbers: a table as CSV and markdown, and its figures."""

from __future__ import annotations

import csv
from pathlib import Path


def write_table(rows: list[dict], columns: list[str], path_base: Path, title: str) -> None:
    """``<base>.csv`` and ``<base>.md`` with the given columns."""
    path_base.parent.mkdir(parents=True, exist_ok=True)
    with open(path_base.with_suffix(".csv"), "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=columns)
        w.writeheader()
        for r in rows:
            w.writerow({c: r.get(c, "") for c in columns})
    lines = [f"**{title}**", "", "| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(str(r.get(c, "")) for c in columns) + " |" for r in rows]
    path_base.with_suffix(".md").write_text("\n".join(lines) + "\n")



def save(fig, path: Path) -> None:
    """Lay out, write at 110 dpi and close a figure."""
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    pyplot().close(fig)


def pyplot():
    """matplotlib.pyplot on the file-only backend."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt
