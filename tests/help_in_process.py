"""A command line's ``--help`` run inside the test process, as ``python ...`` would run it.

The documented commands and the benchmarks are many and each fresh interpreter imports
torch, CasADi and the project again (1-10 s per command, most of it imports); in one
process the imports are paid once. The command runs as ``__main__`` (``runpy``) with its
``sys.argv``, in the repository root, its standard output captured; what it changes of the
process (``sys.argv``, the environment, the working folder, Hydra's global state) is put
back afterwards.
"""

from __future__ import annotations

import contextlib
import io
import os
import runpy
import sys
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def help_in_process(command: tuple[str, ...]) -> tuple[int, str]:
    """(exit status, standard output) of ``python *command --help`` run in this process:
    ``command`` is ``("-m", module, *args)`` or ``(script, *args)``, a script relative to
    the repository root."""
    if command[0] == "-m":
        program, args = command[1], list(command[2:])
    else:
        program, args = str(ROOT / command[0]), list(command[1:])
    saved_argv, saved_path = sys.argv, sys.path[:]
    saved_env, saved_cwd = dict(os.environ), os.getcwd()
    out, status = io.StringIO(), 0
    try:
        os.chdir(ROOT)
        sys.argv = [program, *args, "--help"]
        if command[0] != "-m":
            sys.path.insert(0, str(Path(program).parent))  # as the interpreter puts it
        with contextlib.redirect_stdout(out), warnings.catch_warnings():
            # runpy's note that the module was imported before (by the tests): it runs anew
            warnings.filterwarnings("ignore", "'.*' found in sys.modules", RuntimeWarning)
            try:
                if command[0] == "-m":
                    runpy.run_module(program, run_name="__main__", alter_sys=True)
                else:
                    runpy.run_path(program, run_name="__main__")
            except SystemExit as exit_:
                status = exit_.code if isinstance(exit_.code, int) else int(exit_.code is not None)
    finally:
        sys.argv, sys.path[:] = saved_argv, saved_path
        os.environ.clear()
        os.environ.update(saved_env)
        os.chdir(saved_cwd)
        _clear_hydra()
    return status, out.getvalue()


def _clear_hydra() -> None:
    """A Hydra application's ``--help`` leaves its global state initialized; the next one
    would refuse to initialize it again."""
    if "hydra" not in sys.modules:
        return
    from hydra.core.global_hydra import GlobalHydra

    GlobalHydra.instance().clear()
