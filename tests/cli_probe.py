"""Run the argument parsing of many entry points in one interpreter (tests/test_entry_points.py).

    python tests/cli_probe.py '{"targets": ["dls_quadruped.eval", "experiments.x", "path/x.py"], "argvs": [["--help"]]}'

runs ``python -m TARGET ARGV...`` (or ``python TARGET ARGV...`` for a ``.py`` path) for each target
and each argv through ``runpy``, as the interpreter does (``__name__ == "__main__"``, ``sys.argv``),
with stdout and stderr captured, and prints one JSON object {target: [{"status", "stdout",
"stderr"} per argv]}. Imports
are shared, so torch, MuJoCo and Pinocchio load once instead of once per entry point. An exception
that escapes an entry point is recorded with its traceback in ``stderr`` and status "exception".
"""

from __future__ import annotations

import contextlib
import io
import json
import runpy
import sys
import traceback
import warnings


def probe(target: str, argv: list[str]) -> dict:
    """Exit status (int) and captured output of one entry point run with ``argv``."""
    out, err = io.StringIO(), io.StringIO()
    saved_argv = sys.argv
    status: int | str = 0
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        sys.argv = [target, *argv]
        try:
            if target.endswith(".py"):
                runpy.run_path(target, run_name="__main__")
            else:
                runpy.run_module(target, run_name="__main__", alter_sys=True)
        except SystemExit as exit_:  # what the interpreter does with it: int as is, None 0, else print and 1
            if exit_.code is None or isinstance(exit_.code, int):
                status = exit_.code or 0
            else:
                print(exit_.code, file=sys.stderr)
                status = 1
        except BaseException:  # noqa: BLE001 -- a traceback is the finding
            traceback.print_exc()
            status = "exception"
        finally:
            sys.argv = saved_argv
    return {"status": status, "stdout": out.getvalue(), "stderr": err.getvalue()}


def main() -> None:
    # runpy warns when an earlier target imported this one's ``__main__`` (bench.closed_loop imports
    # closed_loop.__main__); a real ``python -m`` run starts afresh and never sees that
    warnings.filterwarnings("ignore", message=".*found in sys.modules after import of package", category=RuntimeWarning)
    spec = json.loads(sys.argv[1])
    print(json.dumps({t: [probe(t, argv) for argv in spec["argvs"]] for t in spec["targets"]}))


if __name__ == "__main__":
    main()
