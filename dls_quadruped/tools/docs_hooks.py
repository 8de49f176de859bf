"""MkDocs hooks of the documentation site (``mkdocs.yml``: ``hooks:``; built by ``make docs``).

The pages are written to be read in the repository too, so they link to files outside ``docs/`` (the README,
task files, scripts). The site has no such files: :func:`on_page_markdown` turns a relative link whose target
lies outside ``docs/`` into its text followed by the repository path in code (``[README](../README.md)`` ->
``README (`README.md`)``), so the strict build checks every link that stays inside the site and no page
points at a file the site does not have. A link to a folder of results inside ``docs/``
(``[Table 14](table14_warm_start/)``) goes to the folder's own page (``table.md``, ``report.md``, ``README.md``)
where it has one, and is written as its path where it has none. A link to anything that does not exist is left
as it is, so the build reports it.
"""

from __future__ import annotations

import posixpath
import re
from pathlib import Path

LINK = re.compile(r"(?<!!)\[([^\]]+)\]\(([^)\s]+)\)")
"""A markdown link ``[text](target)`` (not an image)."""
FENCE = re.compile(r"^\s*(```|~~~)")
FOLDER_PAGES = ("table.md", "report.md", "README.md", "index.md")
"""The page that stands for a folder a link points at, first found first."""


def outside_target(target: str, page_src: str, docs_dir: Path) -> str | None:
    """The repository path a relative link of the page ``page_src`` (relative to ``docs_dir``) points at when it
    leaves ``docs_dir`` and the file exists; None for any other link (absolute, an anchor, inside the docs)."""
    if re.match(r"^[a-z][a-z0-9+.-]*:", target) or target.startswith(("#", "/")):
        return None
    path = target.split("#", 1)[0]
    joined = posixpath.normpath(posixpath.join(posixpath.dirname(page_src), path))
    if not joined.startswith("../"):
        return None
    repo_path = posixpath.normpath(posixpath.join(docs_dir.name, joined))
    return repo_path if (docs_dir.parent / repo_path).exists() else None


def folder_target(target: str, page_src: str, docs_dir: Path) -> tuple[str, str] | None:
    """For a relative link to a folder inside ``docs_dir``: ("page", the link to its page) when it has one of
    :data:`FOLDER_PAGES`, else ("path", its repository path); None for any other link."""
    if re.match(r"^[a-z][a-z0-9+.-]*:", target) or target.startswith(("#", "/")):
        return None
    path = target.split("#", 1)[0]
    joined = posixpath.normpath(posixpath.join(posixpath.dirname(page_src), path))
    if joined.startswith("../") or not (docs_dir / joined).is_dir():
        return None
    for name in FOLDER_PAGES:
        if (docs_dir / joined / name).is_file():
            return "page", posixpath.join(path.rstrip("/"), name)
    return "path", posixpath.join(docs_dir.name, joined) + "/"


def rewrite_outside_links(markdown: str, page_src: str, docs_dir: Path) -> str:
    """``markdown`` with every link to an existing file outside ``docs_dir`` written as text and its path, and
    every link to a folder inside it sent to the folder's page (fenced code blocks untouched)."""
    out, inside = [], False
    for line in markdown.split("\n"):
        if FENCE.match(line):
            inside = not inside
        if not inside:
            def repl(m: re.Match) -> str:
                text, target = m.group(1), m.group(2)
                folder = folder_target(target, page_src, docs_dir)
                if folder is not None and folder[0] == "page":
                    return f"[{text}]({folder[1]})"
                repo_path = folder[1] if folder is not None else outside_target(target, page_src, docs_dir)
                if repo_path is None:
                    return m.group(0)
                return text if text.strip("`").rstrip("/") == repo_path.rstrip("/") else f"{text} (`{repo_path}`)"
            line = LINK.sub(repl, line)
        out.append(line)
    return "\n".join(out)


def on_page_markdown(markdown: str, page, config, files) -> str:
    """MkDocs hook: links leaving ``docs/`` become repository paths, links to result folders their pages."""
    return rewrite_outside_links(markdown, page.file.src_uri, Path(config["docs_dir"]))
