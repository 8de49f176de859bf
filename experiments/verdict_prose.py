"""The sentences of the section pages that state a verdict, checked against the verdict table
(``experiments/verdicts.py``): a page may not say *reproduced* where the table says *inconclusive*.

Two checks, both run by ``python -m experiments.verdicts --check``:

- :func:`row_mismatches`: for every row of the table, its page section (the row's ``page#anchor``, up to the
  next heading) must state the row's claim (the phrases of :data:`PROSE`, found in that order in one bullet or
  paragraph) and the first verdict word after them must be the table's (``rule alone: X`` and ``X on that
  reading`` name another reading, not the verdict, and are skipped).
- :func:`plan_errors`: a plan's header names the commit that wrote it (``committed at <hash>``), not a time.
- :func:`overclaims`: on the pages of :data:`PAGES`, a sentence that claims an absence ("gone", "no gap",
  "equivalent", "no difference") or convergence must carry what licenses it: a stated margin, or a negation.
"""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DOCS = REPO / "docs"
PAGES = [DOCS / "experiments.md", *sorted((DOCS / "experiments").glob("*.md")), DOCS / "experts.md"]
"""The pages whose prose is scanned for unlicensed absence and convergence claims."""

WORD = re.compile(r"\b(not reproduced|reproduced|contradicted|inconclusive|exploratory)\b")
OTHER_READING = re.compile(r"rule alone:\s*\w+|\b(?:reproduced|contradicted|inconclusive) on that reading")
ACCEPTS = {"not reproduced": {"contradicted", "inconclusive"}}
"""A page word that stands for more than one table label."""

PROSE: dict[str, tuple[str, ...]] = {
    "base ≥ 20 % above rough, speed, climb (reward, simple task)": ('"Base at least 20 % above the other three"',),
    "base reaches almost 2× its trained 1 m/s": ('"Base reaches almost twice its trained speed"',),
    "base 50 % faster in all directions (90 % isoline)": ('"Base goes 50 % faster in all directions"',),
    "climb beats rough on the survival task": ('"Climb is best, even above rough"',),
    "the same on our survival sweep (all difficulties)": ("Climb beats rough",),
    "stairs: every policy drops off after 25 cm": ('"Every policy drops off after 25 cm, even climb"',),
    "CoT ≈ 2 at 0.5 m/s to < 1 at 2.5 m/s": ('"CoT from about 2 at 0.5 m/s to slightly below 1 at 2.5 m/s"',),
    "speed's CoT above base's up to 1.1 m/s": ('"Speed\'s CoT is above base\'s up to 1.1 m/s"',),
    "speed switches to a trot-gallop hybrid at 1.1 m/s": ('"Speed switches to a hybrid',),
    "naive IL has the lower test MSE": ("Naive has the lower MSE",),
    "DAgger ≫ naive IL in SP": ("DAgger ≫ naive in SP",),
    "the same, with 15 000 datapoints, plain evaluation (plan committed before the run)":
        ('"DAgger ≫ naive" at 15 000 datapoints, plain',),
    "the same, 50 000 datapoints, one command per episode, plain evaluation":
        ('"DAgger ≫ naive" at 50 000 datapoints, narrow collection, plain',),
    "SP falls as the batch grows": ("SP falls as the batch grows",),
    "selector α = 0.6 is best": ('"alpha = 0.6 is best"',),
    "α = 0.9: lower SP although lower MSE": ('"alpha = 0.9: lower SP although lower MSE"',),
    "spline p at dt 0.04 s, H 15 drops (rows 33-34)": ("Rows 33-34 (spline p, dt 0.04 s, H = 15) drop",),
    "first-spline is the best encoding": ('"First-spline is the best encoding"',),
    "RL warm start rescues discrete F (naive IC 855-984)": ('"RL warm start rescues the discrete-F encodings"',),
    "the MPC lowers the RL policy's initial cost": ('"The MPC lowers the RL policy\'s initial cost"',),
    "RL warm start earns more reward than naive": ('"RL warm start earns more reward than naive"',),
    "the RL policy alone has the best reward": ('"The RL policy alone has the best reward"',),
    "the RL warm start starts above naive, also from a policy trained on the MPC's cost (preregistered)":
        ("The negative result with the 5.3 policy",),
    "training on the MPC's cost lowers the warm start's IC below the DAgger student's":
        ("Secondary 1 (5.3 − DAgger student as warm starts)",),
    "RL initial cost rises with the horizon": ("RL initial cost rises with the horizon",),
    "naive exception: 0.1 s costlier than 0.2 s": ("The naive 0.1 s exception (0.1 s costlier than 0.2 s)",),
    "RL below naive at 0.1 s": ("RL below naive at short horizons", "at 0.1 s"),
    "RL below naive at 0.2 s (dt 0.04 s)": ("RL below naive at short horizons", "at 0.2 s"),
    "the last predicted steps explode at every horizon": ('"the latest costs systematically explode',),
    "RL warm start less sensitive to M": ('"The RL warm start makes the controller less sensitive to M"',),
    "gait optimisation destabilises (naive, 0.5 m/s)": ("Gait optimisation destabilises the naive controller",),
    "1.5 m/s: the RL warm start falls, RL alone does not":
        ("At 1.5 m/s the RL warm start falls and the RL baseline does not",),
    "the naive MPC survives 1.5 m/s": ('"The naive MPC survives 84.2 % at 1.5 m/s"',),
    "the MPC lowers each policy's initial cost": ('"The MPC lowers each policy\'s initial cost"',),
    "speed's warm start loses 26 survival points": ('"Speed\'s warm start loses 26 survival points (74 %)"',),
    "two warm starts average, not combine, their policies":
        ('"Two warm starts average their policies rather than take the best"',),
    "the MPC raises base's survival by 38 %": ('"The MPC raises base\'s survival by 38 %"',),
    "the same, on flat ground with pushes (preregistered)": ('"The MPC raises base\'s survival"',),
    "the same, rerun with the retrained base and its student (plan amended before the run)":
        ('"The MPC raises base\'s survival"',),
    "two warm starts survive 0 % on the survival task": ('"Two warm starts survive 0 %"',),
    "at 1.5 m/s the two help each other": ('"At 1.5 m/s the two help each other',),
    "coexistence is detrimental at 0.1 m/s": ('"At the other two speeds coexistence is detrimental"', "at 0.1 m/s"),
    "coexistence is detrimental at 0.5 m/s": ('"At the other two speeds coexistence is detrimental"', "at 0.5 m/s"),
    "the argmin switches policy often (up to 10 /s)": ('"the argmin switches policy often, up to 10 times a second"',),
}
"""Each row's claim (``Row.claim``) -> the phrases its page states it with, in the order they appear."""

ABSENCE = re.compile(r"\bgone\b|\bno gap\b|\bequivalen\w*|\bno difference\b", re.IGNORECASE)
CONVERGE = re.compile(r"\bconverge[sd]?\b", re.IGNORECASE)
MARGIN = re.compile(r"margin|±|\bnot\b|\bcannot\b", re.IGNORECASE)
NEGATION = re.compile(r"\bnot\b|\bno longer\b|\bnever\b", re.IGNORECASE)
COMMITTED = re.compile(r"\bcommitted at ([0-9a-f]{7,40})\b")
WRITTEN = re.compile(r"\bwritten \d{4}-\d{2}-\d{2}")
ABBREVIATIONS = re.compile(r"\b(Figs?|Eq|e\.g|i\.e|vs|cf)\.\s")


def slug(heading: str) -> str:
    """A markdown heading's anchor, as the site and GitHub make it."""
    return re.sub(r"[^\w\- ]", "", heading.lstrip("#").strip().lower()).replace(" ", "-")


def blocks(lines: list[str]) -> list[str]:
    """The bullets and paragraphs of some markdown lines, each joined into one line with the bold markers removed;
    tables, code and headings are left out."""
    out, cur = [], []
    for line in lines:
        start = line.startswith(("- ", "* ", "|", "    ", "#", "![")) or not line.strip()
        if start and cur:
            out.append(" ".join(cur))
            cur = []
        if line.strip() and not line.startswith(("|", "    ", "#", "![")):
            cur.append(line.strip())
    if cur:
        out.append(" ".join(cur))
    return [re.sub(r"\s+", " ", b.replace("**", "")) for b in out]


def section(page: str) -> list[str]:
    """The lines of ``file.md#anchor`` under ``docs/experiments/``: from the heading to the next heading."""
    name, _, anchor = page.partition("#")
    lines = (DOCS / "experiments" / name).read_text(encoding="utf-8").splitlines()
    starts = [i for i, line in enumerate(lines) if line.startswith("#") and slug(line) == anchor]
    if not starts:
        raise KeyError(f"{name} has no section #{anchor}")
    rest = lines[starts[0] + 1:]
    end = next((i for i, line in enumerate(rest) if line.startswith("#")), len(rest))
    return rest[:end]


def stated(text: str, phrases: tuple[str, ...]) -> list[str]:
    """The verdict words that ``text``'s bullets and paragraphs state after ``phrases`` (in order in one block)."""
    words = []
    for b in blocks(text.splitlines()):
        pos, low = 0, b.lower()
        for ph in phrases:
            pos = low.find(ph.lower(), pos)
            if pos < 0:
                break
            pos += len(ph)
        else:
            m = WORD.search(OTHER_READING.sub("", low[pos:]))
            if m:
                words.append(m.group(1))
    return words


def row_mismatches(rows: list) -> list[str]:
    """One line per row whose page does not state the table's verdict (see the module's docstring)."""
    out = []
    for r in rows:
        phrases = PROSE.get(r.claim)
        if phrases is None:
            out.append(f"{r.ref} '{r.claim}': no phrase in verdict_prose.PROSE")
            continue
        word = r.word(r.ours())
        said = stated("\n".join(section(r.page)), phrases)
        if not said:
            out.append(f"{r.ref} '{r.claim}': {r.page} states no verdict after {' ... '.join(phrases)!r}")
        for w in said:
            if w != word and word not in ACCEPTS.get(w, ()):
                out.append(f"{r.ref} '{r.claim}': {r.page} says {w!r}, the table {word!r}")
    return out


def sentences(block: str) -> list[str]:
    """A block cut into sentences (abbreviations such as "Fig. 18" do not end one)."""
    protected = ABBREVIATIONS.sub(lambda m: m.group(0).replace(". ", "\0"), block)
    return [s.replace("\0", ". ") for s in re.split(r"(?<=[.!?])\s+(?=[A-Z\"(\[])", protected)]


def overclaims(pages: list[Path] | None = None) -> list[str]:
    """Sentences that claim an absence without a margin or a negation, or convergence without a negation
    (``pages``: :data:`PAGES` by default)."""
    out = []
    for page in PAGES if pages is None else pages:
        text = page.read_text(encoding="utf-8")
        for b in blocks(text.splitlines()):
            for s in sentences(b):
                if (ABSENCE.search(s) and not MARGIN.search(s)) or (CONVERGE.search(s) and not NEGATION.search(s)):
                    out.append(f"{page.name}: {s[:160]!r}")
    return out


def _git(repo: Path, *args: str) -> str:
    return subprocess.run(["git", "-C", str(repo), *args], capture_output=True, text=True, check=True).stdout


def plan_errors(repo: Path = REPO, folder: str = "docs/experiments") -> list[str]:
    """Plan headers that do not name the commit that wrote them.

    A heading of a page under ``folder`` that says ``(... committed at <hash> ...)`` must name a commit that exists
    and whose diff adds that heading (the text before its parenthesis); the first heading of a ``*_plan.md`` must
    name the commit that added the file (``git log --diff-filter=A``); no heading may carry a hand-written time
    (``written 2026-...``). Raises ``subprocess.CalledProcessError`` where ``repo`` is not a git work tree."""
    out = []
    for page in sorted((repo / folder).glob("*.md")):
        rel = page.relative_to(repo).as_posix()
        headings = [line for line in page.read_text(encoding="utf-8").splitlines() if line.startswith("#")]
        for h in headings:
            if WRITTEN.search(h):
                out.append(f"{rel}: {h!r} carries a hand-written time, not its commit")
            m = COMMITTED.search(h)
            if m is None:
                continue
            try:
                full = _git(repo, "rev-parse", "--verify", "--quiet", m.group(1) + "^{commit}").strip()
            except subprocess.CalledProcessError:
                out.append(f"{rel}: {h!r} names {m.group(1)}, not a commit of this repository")
                continue
            title = h.split(" (", 1)[0]
            if not any(line == "+" + title or line.startswith("+" + title + " (")
                       for line in _git(repo, "show", "--format=", full, "--", rel).splitlines()):
                out.append(f"{rel}: {h!r} names {m.group(1)}, which did not add that heading")
        if page.name.endswith("_plan.md"):
            added = _git(repo, "log", "--diff-filter=A", "--format=%H", "--", rel).split()
            m = COMMITTED.search(headings[0]) if headings else None
            if m is None or not added or not added[-1].startswith(m.group(1)):
                out.append(f"{rel}: its first heading must name the commit that added the file "
                           f"({added[-1][:7] if added else 'not committed'})")
    return out
