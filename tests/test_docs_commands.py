"""Every command the docs name exists: make targets and variables, ``python -m`` modules and their flags,
experiment scripts, and the repository files and links the pages point at.

The pages are ``README.md``, ``docs/*.md``, ``docs/{experiments,reports,tasks,tutorials}/*.md`` and
``docs/policies/README.md``, the result reports included
(the command lines they quote as records of past runs must still name what exists). Commands are read from
shell code blocks, indented code lines and inline code spans; a command is ``make ...``, ``python -m MODULE ...``
(also ``.venv/bin/python``, ``torchrun ... -m MODULE``; the experiments are ``python -m experiments.SCRIPT``),
``python SCRIPT.py ...``, ``bash SCRIPT.sh`` or ``tensorboard ...``. What is checked:

* ``make TARGET VAR=VALUE``: the target is a rule of the Makefile and the variable is one the Makefile
  sets or reads; flags inside a variable that the Makefile passes to a module (``DEMO_ARGS="--samples 1"``)
  are checked against that module's parser;
* ``python -m MODULE --flag`` (a module of ``dls_quadruped`` or ``experiments``): the module exists
  (``pkg/__main__.py`` for a package) and every ``--flag``
  is an option of the parser its ``--help`` builds; the parsers come from one subprocess that runs every
  module's ``--help`` with ``argparse.ArgumentParser.print_help`` patched to record the options
  (``runpy``, as ``tests/cli_probe.py``: torch, MuJoCo and Pinocchio load once);
* a token or inline span that is a repository path (``docs/policies/base_actor.pt``, ``envs/mdp/``,
  ``tests/x.py::test_y``) exists, relative to the repository, the package or the page; placeholders
  (``<run>``, ``*``, ``{a,b}``, ``...``) and what commands write (``runs/``, ``results/``, the files of
  a run directory, :data:`OUTPUTS`) are skipped;
* a page that says what a target runs (``make bench-ppo` = `python -m dls_quadruped.bench.ppo_update ...``)
  names the module of the target's recipe, and each flag value it gives is the recipe's, or the parser's
  default where the recipe passes none;
* a relative markdown link ``[text](path)`` points at a file;
* the README and the gymnasium page name every task of ``tasks/``.
"""

from __future__ import annotations

import importlib.util
import json
import os
import re
import shlex
import subprocess
import sys
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PAGES = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md")),
         *(p for sub in ("experiments", "reports", "tasks",
                         "tutorials") for p in sorted((REPO / "docs" / sub).glob("*.md"))),
         REPO / "docs" / "policies" / "README.md"]

OUTPUTS = ("runs/", "results/", "exported/", "dataset/", "selection/", "play/", "cells/", "wheels/",
           "wheelhouse/", "test/", "runB/", "runA/")
"""Path prefixes of what the commands write (run and output folders), not repository files."""
PLACEHOLDER = re.compile(r"[<>*{}$~…]|\.\.\.|\bRUN\b|\bDIR\b|\bPATH\b|\bCKPT\b")
RANGE = re.compile(r"[a-z][0-9]+-[0-9]+$")
"""``experiments/fig17-23``: a range of files."""
OUTPUT_FLAGS = {"--checkpoint-copy", "--out", "--out-dir", "--run-dir", "--csv", "--png", "--export"}
PATH_ROOTS = ("dls_quadruped/", "docs/", "tasks/", "tests/", "experiments/")
"""A token inside a command is taken for a repository path when it starts with one of these."""
PATH_LIKE = re.compile(r"^[\w.\-]+(?:/[\w.\-]+)*/?(?:::[\w\[\]\-]+)?$")
FLAG = re.compile(r"^[\[(|]*(--[A-Za-z0-9][\w-]*)")
PYTHON = re.compile(r"(^|/)python[0-9.]*$")
SHELL_FENCES = {"", "bash", "sh", "shell", "console", "text"}


# ---------------------------------------------------------------------------------------------------
# Reading the pages


def _fenced_blocks(text: str) -> tuple[list[str], str]:
    """Shell code blocks of ``text`` and the text with every fenced block blanked out."""
    blocks, rest, inside, info, lines = [], [], False, "", []
    for line in text.splitlines():
        fence = re.match(r"^\s*(```|~~~)\s*([\w-]*)", line)
        if fence and not inside:
            inside, info, lines = True, fence.group(2).lower(), []
            rest.append("")
        elif fence and inside:
            inside = False
            if info in SHELL_FENCES:
                blocks.append("\n".join(lines))
            rest.append("")
        elif inside:
            lines.append(line)
            rest.append("")
        else:
            rest.append(line)
    return blocks, "\n".join(rest)


def _join_continuations(lines: list[str]) -> list[str]:
    """Shell lines with trailing backslashes joined."""
    out, cur = [], ""
    for line in lines:
        if line.rstrip().endswith("\\"):
            cur += line.rstrip()[:-1] + " "
        else:
            out.append(cur + line)
            cur = ""
    if cur:
        out.append(cur)
    return out


def _inline_spans(text: str) -> list[str]:
    """Inline code spans of markdown text without fenced blocks (a span may wrap over lines)."""
    spans = []
    for para in re.split(r"\n\s*\n", text):
        for m in re.finditer(r"(`+)(.+?)\1", para, flags=re.DOTALL):
            spans.append(" ".join(m.group(2).split()))
    return spans


@dataclass
class Page:
    path: Path
    code_lines: list[str] = field(default_factory=list)
    """Shell lines of code blocks and indented code lines, continuations joined."""
    spans: list[str] = field(default_factory=list)
    """Inline code spans."""
    links: list[str] = field(default_factory=list)
    """Targets of relative markdown links."""

    @property
    def name(self) -> str:
        return self.path.relative_to(REPO).as_posix()


@cache
def read_page(path: Path) -> Page:
    text = path.read_text(encoding="utf-8")
    blocks, prose = _fenced_blocks(text)
    page = Page(path)
    for block in blocks:
        page.code_lines += _join_continuations(block.splitlines())
    indented = [line for line in prose.splitlines() if re.match(r"^( {4,}|\t)\S", line)]
    page.code_lines += [line for line in _join_continuations(indented) if _starts_command(line)]
    page.spans = _inline_spans(prose)
    page.links = [m.group(1) for m in re.finditer(r"\]\(([^)\s]+)\)", prose)
                  if not re.match(r"^[a-z]+:|^#", m.group(1))]
    return page


def _starts_command(line: str) -> bool:
    words = line.split()
    while words and re.match(r"^[A-Z_][A-Z0-9_]*=", words[0]):  # FOO=1 make ...
        words = words[1:]
    return bool(words) and (words[0] == "make" or PYTHON.search(words[0]) is not None
                            or words[0] in ("torchrun", "tensorboard", "bash", "sh"))


# ---------------------------------------------------------------------------------------------------
# Commands


@dataclass(frozen=True)
class Command:
    kind: str
    """'make', 'module', 'script' (python), 'shell' (a shell script) or 'program'."""
    name: str
    """Make target(s) joined by spaces, module, script path or program."""
    flags: tuple[str, ...] = ()
    variables: tuple[tuple[str, str], ...] = ()
    """make's VAR=VALUE pairs."""
    paths: tuple[str, ...] = ()
    """Repository paths among the arguments."""


def _tokens(line: str) -> list[str]:
    line = re.sub(r"(;|&&|\|\|)(\s|$)", r" \1 ", line)  # "a; b" -> "a ; b": shlex keeps "a;" whole
    try:
        return shlex.split(line, comments=True)
    except ValueError:  # an unbalanced quote in prose: split on blanks
        return line.split("#")[0].split()


def _repo_paths(tokens: list[str]) -> tuple[str, ...]:
    """Arguments (or ``--flag=value`` / ``VAR=value`` values) that name repository files."""
    out = []
    for tok in tokens:
        value = tok.split("=", 1)[1] if re.match(r"^(--[\w-]+|[A-Z_][A-Z0-9_]*)=", tok) else tok
        value = value.strip("[](),;")
        if value.startswith(PATH_ROOTS) and PATH_LIKE.match(value) and not PLACEHOLDER.search(value):
            out.append(value)
    return tuple(out)


def _flags(tokens: list[str]) -> tuple[str, ...]:
    return tuple(m.group(1) for tok in tokens if (m := FLAG.match(tok)))


def parse_commands(line: str) -> list[Command]:
    """The commands of one shell line (``;``, ``&&`` and ``||`` separate commands)."""
    commands = []
    segment: list[str] = []
    for tok in [*_tokens(line), ";"]:
        if tok not in (";", "&&", "||"):
            segment.append(tok)
            continue
        words, segment = segment, []
        while words and re.match(r"^[A-Z_][A-Z0-9_]*=", words[0]):
            words = words[1:]
        if not words:
            continue
        head = words[0]
        if head == "make":
            args = words[1:]
            targets = [a for a in args if re.match(r"^[a-z][\w.-]*$", a)]
            variables = tuple(tuple(a.split("=", 1)) for a in args if re.match(r"^[A-Z_][A-Z0-9_]*=", a))
            commands.append(Command("make", " ".join(targets), (), variables, _repo_paths(args)))
        elif PYTHON.search(head) or head == "torchrun":
            if "-m" in words and words.index("-m") + 1 < len(words):
                i = words.index("-m")
                rest = words[i + 2:]
                commands.append(Command("module", words[i + 1], _flags(rest), (), _repo_paths(rest)))
            elif len(words) > 1 and words[1].endswith(".py") and PYTHON.search(head):
                rest = words[2:]
                commands.append(Command("script", words[1], _flags(rest), (), _repo_paths(rest)))
        elif head == "tensorboard":
            commands.append(Command("program", head, _flags(words[1:]), (), _repo_paths(words[1:])))
        elif head in ("bash", "sh") and len(words) > 1 and words[1].endswith(".sh"):
            commands.append(Command("shell", words[1], (), (), _repo_paths(words[1:])))
    return commands


def page_commands(page: Page) -> list[Command]:
    out = []
    for line in page.code_lines + page.spans:
        if _starts_command(line):
            out += parse_commands(line)
    return out


def all_commands() -> list[tuple[str, Command]]:
    return [(page.name, cmd) for path in PAGES for page in [read_page(path)] for cmd in page_commands(page)]


# ---------------------------------------------------------------------------------------------------
# The Makefile


@cache
def makefile() -> tuple[frozenset[str], frozenset[str], dict[str, str]]:
    """Targets, variables and {VAR_ARGS: module} of the Makefile (a variable spliced into a ``-m`` recipe)."""
    text = (REPO / "Makefile").read_text()
    targets = set()
    for m in re.finditer(r"^([A-Za-z0-9_.\- ]+?)\s*:(?!=)", text, flags=re.MULTILINE):
        targets.update(t for t in m.group(1).split() if not t.startswith("."))
    variables = set(re.findall(r"^([A-Z_][A-Z0-9_]*)\s*[?:+]?=", text, flags=re.MULTILINE))
    variables |= set(re.findall(r"\$\(([A-Z_][A-Z0-9_]*)\)", text))
    variables |= set(re.findall(r"\$\(origin ([A-Z_][A-Z0-9_]*)\)", text))
    passes = {}
    for recipe in re.split(r"(?<!\\)\n", text):
        if m := re.search(r"-m (dls_quadruped[\w.]*)", recipe):
            for var in re.findall(r"\$\(([A-Z_][A-Z0-9_]*ARGS)\)", recipe):
                passes[var] = m.group(1)
    return frozenset(targets), frozenset(variables), passes


@cache
def recipe(target: str) -> str:
    """The shell lines of a Makefile rule, continuations joined ('' if there is none)."""
    text = (REPO / "Makefile").read_text().replace("\\\n", " ")
    m = re.search(rf"^{re.escape(target)}\s*:(?!=)[^\n]*\n((?:\t[^\n]*\n?)+)", text, flags=re.MULTILINE)
    return m.group(1) if m else ""


def literal_flags(words: list[str]) -> dict[str, tuple[str, ...]]:
    """{--flag: its literal values} of an argument list (flags built from make variables left out)."""
    out: dict[str, tuple[str, ...]] = {}
    flag = None
    for w in words:
        if "$(" in w or w.startswith("$"):
            if flag is not None and not out[flag]:
                del out[flag]  # --out $(OUT)/bench: a value make fills in
            flag = None
        elif w.startswith("--"):
            flag = w.split("=")[0]
            out[flag] = (w.split("=", 1)[1],) if "=" in w else ()
        elif flag is not None:
            out[flag] += (w,)
    return out


def same_values(a: tuple[str, ...], b: tuple[str, ...]) -> bool:
    """Equal argument values, numbers compared as numbers (``8`` is a default ``8.0``)."""
    def norm(v: str) -> object:
        try:
            return float(v)
        except ValueError:
            return v
    return len(a) == len(b) and all(norm(x) == norm(y) for x, y in zip(a, b))


EQUATION = re.compile(r"`make ([\w-]+)`\s*(?:=|\()\s*`([^`]+)`")
"""``make T` = `python -m M ...`` or ``make T` (`python -m M ...`)``: a page saying what a target runs."""


# ---------------------------------------------------------------------------------------------------
# Parsers of the entry points

PROBE = r"""
import argparse, contextlib, io, json, runpy, sys, warnings
warnings.filterwarnings("ignore")
def record(self, file=None):
    defaults = {}
    for action in self._actions:
        d = action.default
        if action.nargs != 0 and d is not None and d is not argparse.SUPPRESS:
            for opt in action.option_strings:
                defaults[opt] = [str(x) for x in d] if isinstance(d, (list, tuple)) else [str(d)]
    raise _Help(sorted(self._option_string_actions), defaults)
class _Help(BaseException):
    pass
argparse.ArgumentParser.print_help = record
out = {}
for target in json.loads(sys.argv[1]):
    sys.argv = [target, "--help"]
    try:
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
            if target.endswith(".py"):
                runpy.run_path(target, run_name="__main__")
            else:
                runpy.run_module(target, run_name="__main__", alter_sys=True)
        out[target] = {"error": "--help printed no argparse usage"}
    except _Help as h:
        out[target] = {"options": h.args[0], "defaults": h.args[1]}
    except BaseException as err:
        out[target] = {"error": f"{type(err).__name__}: {err}"}
print(json.dumps(out))
"""


def _module_file(module: str) -> Path | None:
    """The file ``python -m module`` runs, for a module of this repository (None if there is none)."""
    base = REPO / Path(*module.split("."))
    for candidate in (base.with_suffix(".py"), base / "__main__.py"):
        if candidate.is_file():
            return candidate
    return None


@cache
def parsers(targets: tuple[str, ...]) -> dict[str, dict]:
    """{target: {"options": [...]} or {"error": ...}} from one interpreter."""
    if not targets:
        return {}
    env = {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1", "MUJOCO_GL": "disable"}
    run = subprocess.run([sys.executable, "-c", PROBE, json.dumps(list(targets))], cwd=REPO, capture_output=True,
                         text=True, timeout=300, check=False, env=env)
    assert run.returncode == 0, run.stderr[-3000:]
    return json.loads(run.stdout.strip().splitlines()[-1])


def project_targets(commands: list[tuple[str, Command]]) -> tuple[str, ...]:
    """Modules of this repository (the package's and the experiments') and scripts the docs run (the ones whose
    flags are checked)."""
    _, _, passes = makefile()
    targets = {c.name for _, c in commands if c.kind == "module" and _module_file(c.name)}
    targets |= {c.name for _, c in commands if c.kind == "script" and "/" in c.name and (REPO / c.name).is_file()}
    targets |= {passes[v] for _, c in commands if c.kind == "make" for v, _ in c.variables if v in passes}
    return tuple(sorted(targets))


# ---------------------------------------------------------------------------------------------------
# Paths


def _path_exists(path: str, page: Path) -> bool:
    file, _, test = path.partition("::")
    for base in (REPO, REPO / "dls_quadruped", page.parent):
        candidate = base / file
        if candidate.exists():
            if test:
                name = test.split("[")[0]
                pattern = rf"^\s*(?:async )?def {re.escape(name)}\b"
                return re.search(pattern, candidate.read_text(), flags=re.MULTILINE) is not None
            return True
    return False


def _is_checked_path(span: str, page: Path = REPO / "docs" / "x.md") -> bool:
    """A path into the repository: its first folder is one of the repository, the package or the page's folder
    (so TensorBoard tags ``Loss/value`` and gymnasium ids ``dls_quadruped/Base-v0`` are not taken for paths)."""
    if "/" not in span or PATH_LIKE.match(span) is None or PLACEHOLDER.search(span) or span.startswith(OUTPUTS):
        return False
    if RANGE.search(span) or re.search(r"-v[0-9]+$", span):  # experiments/table14-17: several scripts; a gym id
        return False
    if span.startswith(".git/"):  # git's own files (.git/info/exclude) are the clone's, not the repository's
        return False
    first = span.split("/")[0]
    return any((base / first).is_dir() for base in (REPO, REPO / "dls_quadruped", page.parent))


def page_outputs(page: Page) -> set[str]:
    """Paths the page's own commands write (``CHECKPOINT_COPY=P``, ``--checkpoint-copy P``, ``--out P``, ...):
    a later command of the page may read them."""
    out = set()
    for line in page.code_lines + page.spans:
        if not _starts_command(line):
            continue
        tokens = _tokens(line)
        for i, tok in enumerate(tokens):
            if m := re.match(r"^[A-Z_]*(?:OUT|COPY)=(.+)$", tok):
                out.add(m.group(1))
            elif tok in OUTPUT_FLAGS and i + 1 < len(tokens):
                out.add(tokens[i + 1])
            elif tok.split("=")[0] in OUTPUT_FLAGS and "=" in tok:
                out.add(tok.split("=", 1)[1])
    return out


# ---------------------------------------------------------------------------------------------------
# Tests


def test_the_reader_finds_commands_flags_and_paths():
    cmds = parse_commands("OMP_NUM_THREADS=1 .venv/bin/python -m dls_quadruped.eval --policy docs/policies/x.pt "
                          "[--episodes 256] # a comment --not-a-flag")
    assert cmds == [Command("module", "dls_quadruped.eval", ("--policy", "--episodes"), (), ("docs/policies/x.pt",))]
    (make,) = parse_commands('make demo DEMO_ARGS="--samples 25000 --naive-share 0.5" EXPERT=runs/base/<run>/p.pt')
    assert make.name == "demo" and make.variables == (("DEMO_ARGS", "--samples 25000 --naive-share 0.5"),
                                                      ("EXPERT", "runs/base/<run>/p.pt")) and make.paths == ()
    torchrun = parse_commands("torchrun --standalone --nproc_per_node=2 -m dls_quadruped.learning.train --task base")
    assert torchrun == [Command("module", "dls_quadruped.learning.train", ("--task",))]
    assert [c.kind for c in parse_commands("make install-gpu && python experiments/t.py --scale small; ls")] == \
        ["make", "script"]
    assert parse_commands("bash experiments/make_students.sh table14") == [
        Command("shell", "experiments/make_students.sh", (), (), ("experiments/make_students.sh",))]
    page = Page(REPO / "x.md")
    blocks, prose = _fenced_blocks("a\n```python\nmake x\n```\n```bash\nmake a \\\n  B=1\n```\n`make\nb` c")
    assert blocks == ["make a \\\n  B=1"] and _join_continuations(blocks[0].splitlines()) == ["make a    B=1"]
    assert _inline_spans(prose) == ["make b"] and page.name == "x.md"
    assert _is_checked_path("docs/policies/base_actor.pt") and _is_checked_path("envs/mdp/")
    assert not _is_checked_path("runs/base/<run>/model_<it>.pt") and not _is_checked_path("docs/x{,_medium}.json")
    assert not _is_checked_path("results/demo/summary.json") and not _is_checked_path("/proc/cpuinfo")
    assert not _is_checked_path("Loss/train_mse") and not _is_checked_path("dls_quadruped/Base-v0")
    assert not _is_checked_path("experiments/table14-17") and _is_checked_path("bench/tracking.py")
    assert not _is_checked_path(".git/info/exclude") and _is_checked_path(".ci/run")
    lines = ["make train CHECKPOINT_COPY=docs/p.pt", "python -m m --out-dir d/e --out=f/g"]
    assert page_outputs(Page(REPO / "x.md", code_lines=lines)) == {"docs/p.pt", "d/e", "f/g"}


def test_the_makefile_reader_knows_targets_variables_and_pass_through_flags():
    targets, variables, passes = makefile()
    assert {"demo", "test", "train", "play", "eval", "distill", "bench", "bench-mpc", "tasks"} <= targets
    assert {"TASK", "NUM_ENVS", "CHECKPOINT", "SET", "UPDATE_DOCS", "TORCH_INDEX"} <= variables
    assert passes["DEMO_ARGS"] == "dls_quadruped.closed_loop"
    assert passes["DISTILL_ARGS"] == "dls_quadruped.learning.distill"


def test_the_pages_name_commands():
    found = all_commands()
    assert len(PAGES) > 10 and len(found) > 100
    assert {c.name for _, c in found if c.kind == "module"} >= {"dls_quadruped.eval", "dls_quadruped.closed_loop",
                                                                 "dls_quadruped.eval.select"}
    assert any(page == "docs/workflow.md" for page, _ in found)


def test_make_targets_and_variables_exist():
    targets, variables, _ = makefile()
    wrong = []
    for page, cmd in all_commands():
        if cmd.kind != "make":
            continue
        wrong += [f"{page}: make {t}: no such target" for t in cmd.name.split() if t not in targets]
        wrong += [f"{page}: make {cmd.name} {v}=: the Makefile has no variable {v}" for v, _ in cmd.variables
                  if v not in variables]
    assert not wrong, "\n".join(sorted(set(wrong)))


def test_modules_scripts_and_flags_exist():
    commands = all_commands()
    _, _, passes = makefile()
    probed = parsers(project_targets(commands))
    wrong = []

    def check_flags(page: str, target: str, flags: tuple[str, ...], how: str) -> None:
        info = probed.get(target, {"error": "not probed"})
        if "error" in info:
            wrong.append(f"{page}: {how}: --help fails ({info['error']})")
            return
        wrong.extend(f"{page}: {how}: {target} has no option {f}" for f in flags if f not in info["options"])

    for page, cmd in commands:
        if cmd.kind == "module":
            if PLACEHOLDER.search(cmd.name):
                continue  # python -m experiments.<script>: any of them
            if cmd.name.split(".")[0] in ("dls_quadruped", "experiments"):
                if _module_file(cmd.name) is None:
                    wrong.append(f"{page}: python -m {cmd.name}: no such module")
                else:
                    check_flags(page, cmd.name, cmd.flags, f"python -m {cmd.name}")
            elif importlib.util.find_spec(cmd.name.split(".")[0]) is None:
                wrong.append(f"{page}: python -m {cmd.name}: not installed")
        elif cmd.kind == "script":
            if "/" not in cmd.name or PLACEHOLDER.search(cmd.name):
                continue  # a file the page asks the reader to write (docs/gymnasium.md's ppo.py)
            if not (REPO / cmd.name).is_file():
                wrong.append(f"{page}: python {cmd.name}: no such script")
            else:
                check_flags(page, cmd.name, cmd.flags, f"python {cmd.name}")
        elif cmd.kind == "shell" and not (REPO / cmd.name).is_file():
            wrong.append(f"{page}: bash {cmd.name}: no such script")
        elif cmd.kind == "program" and importlib.util.find_spec(cmd.name) is None:
            wrong.append(f"{page}: {cmd.name}: not installed")
        elif cmd.kind == "make":
            for var, value in cmd.variables:
                if var in passes and value.startswith("-"):
                    check_flags(page, passes[var], _flags(value.split()), f"make {cmd.name} {var}")
    assert not wrong, "\n".join(sorted(set(wrong)))


def test_referenced_repository_files_exist():
    wrong = []
    for path in PAGES:
        page = read_page(path)
        spans = [s for s in page.spans if _is_checked_path(s, path)]
        args = [p for cmd in page_commands(page) for p in cmd.paths]
        written = page_outputs(page)
        wrong += [f"{page.name}: `{p}` does not exist" for p in spans + args
                  if p not in written and not _path_exists(p, path)]
        wrong += [f"{page.name}: link ({link}) does not exist" for link in page.links
                  if not (path.parent / link.split("#")[0]).exists()]
    assert not wrong, "\n".join(sorted(set(wrong)))


def test_what_a_page_says_a_target_runs_is_what_it_runs():
    """``make bench-closed-loop` = `python -m dls_quadruped.bench.closed_loop --robots 16 64``: the target's
    recipe runs that module, and every flag the page gives has the value the recipe passes or, where the
    recipe passes none, the parser's default."""
    assert literal_flags(["--robots", "16", "64", "--out", "$(OUT)/bench", "--paths", "fused"]) == \
        {"--robots": ("16", "64"), "--paths": ("fused",)}
    assert "-m dls_quadruped.bench.closed_loop --robots 16 64" in recipe("bench-closed-loop")
    assert same_values(("8.0", "a"), ("8", "a")) and not same_values(("3",), ("5",))
    wrong, seen = [], 0
    probed = parsers(project_targets(all_commands()))
    for path in PAGES:
        text = " ".join(_fenced_blocks(path.read_text(encoding="utf-8"))[1].split())
        for target, command in EQUATION.findall(text):
            (cmd,) = [c for c in parse_commands(command) if c.kind == "module"] or [None]
            if cmd is None:
                continue
            seen += 1
            rule = recipe(target)
            m = re.search(r"-m ([\w.]+)(.*)", rule)
            if m is None or m.group(1) != cmd.name:
                wrong.append(f"{path.name}: make {target} runs {m.group(1) if m else 'no module'}, not {cmd.name}")
                continue
            ours, theirs = literal_flags(_tokens(command)), literal_flags(m.group(2).split())
            defaults = probed.get(cmd.name, {}).get("defaults", {})
            for f, v in ours.items():
                if f in theirs and not same_values(theirs[f], v):
                    wrong.append(f"{path.name}: make {target} passes {f} {' '.join(theirs[f])}, "
                                 f"the page says {' '.join(v)}")
                elif f not in theirs and v and f in defaults and not same_values(tuple(defaults[f]), v):
                    wrong.append(f"{path.name}: make {target} runs {cmd.name}'s default {f} {' '.join(defaults[f])}, "
                                 f"the page says {' '.join(v)}")
    assert seen >= 5, seen
    assert not wrong, "\n".join(wrong)


@pytest.mark.parametrize("page", [p.relative_to(REPO).as_posix() for p in PAGES])
def test_every_page_is_read(page):
    assert read_page(REPO / page).spans or read_page(REPO / page).code_lines, f"{page}: nothing read"


def test_the_readme_and_the_gymnasium_page_name_every_task():
    """A task file added to ``tasks/`` is listed where a newcomer looks: the README and the gymnasium ids."""
    tasks = sorted(p.stem for p in (REPO / "tasks").glob("*.yaml") if not p.name.startswith("_"))
    readme, gym = (REPO / "README.md").read_text(), (REPO / "docs" / "gymnasium.md").read_text()
    assert {"base", "rough", "speed", "climb"} <= set(tasks)
    missing = [f"README.md: `{t}`" for t in tasks if f"`{t}`" not in readme]
    missing += [f"docs/gymnasium.md: {gid}" for t in tasks
                if (gid := f"dls_quadruped/{''.join(w.capitalize() for w in t.split('_'))}-v0") not in gym]
    assert not missing, "tasks not named: " + ", ".join(missing)
