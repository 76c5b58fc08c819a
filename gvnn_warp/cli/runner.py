"""How every ``gvnn-warp`` command runs, shared by the package's ``main`` and by each command run on
its own (``python -m gvnn_warp.cli.<command>``): the packages a command needs are checked before it
starts, a bad combination of arguments (``UsageError``) is one line after the usage line (status 2), a
file the command cannot make, read, write or use (``OSError``, ``gvnn_warp.errors.InputError``: a
missing or 8-bit depth PNG, an empty list, a checkpoint of another format) is one line without the
usage text (status 1), and Ctrl-C ends it with one line and status 130.

Imports no command module (the package ``gvnn_warp.cli`` holds the table of commands).
"""

from __future__ import annotations

import argparse
import atexit
import ctypes
import gc
import importlib.util
import os
import signal
import sys
import threading
from collections.abc import Callable, Iterable

import warp as wp

from .. import _warp_setup
from ..errors import InputError
from .args import HelpFormatter, UsageError, plain_text

__all__ = [
    "EXIT_GRACE_SECONDS",
    "INSTALL_HINTS",
    "INTERRUPTED_STATUS",
    "add_command",
    "announce_compiles",
    "command_main",
    "freeze_at_exit",
    "missing_packages",
    "parse_and_run",
    "run_command",
    "tidy_parser",
]

# what to tell a user who lacks a package a command needs
INSTALL_HINTS = {
    "torch": "PyTorch, which is not installed: in the clone, pip install -e '.[torch]' (for the CPU-only build, "
    "first: pip install torch==2.13.0 --index-url https://download.pytorch.org/whl/cpu)",
    # plain dependencies of gvnn_warp: missing only from a broken installation
    "matplotlib": "matplotlib, which is not installed: pip install matplotlib",
    "tqdm": "tqdm, which is not installed: pip install tqdm",
    "evo": "evo (trajectory metrics), which is not installed: pip install evo",
}

INTERRUPTED_STATUS = 130  # 128 + SIGINT, as a shell reports a process ended by Ctrl-C
EXIT_GRACE_SECONDS = 5.0  # after Ctrl-C, the process ends within this time whatever it was doing


def tidy_parser(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Help without markup and with every option's default (see ``HelpFormatter``)."""
    parser.formatter_class = HelpFormatter
    parser.description = plain_text(parser.description)
    return parser


def missing_packages(names: Iterable[str]) -> list[str]:
    """The importable packages among ``names`` that are not installed (found without importing them)."""
    return [n for n in names if importlib.util.find_spec(n) is None]


def announce_compiles() -> None:
    """Print one line on stderr before Warp first compiles a kernel module in this process (a
    cold kernel cache: the first run, or a new gvnn_warp or Warp version); nothing when every
    module comes from the cache. Only rank 0 prints under torchrun."""
    if os.environ.get("RANK", "0") != "0":
        return

    def notify():
        print(f"gvnn-warp: compiling kernels, once (a few seconds per module; cached in "
              f"{wp.config.kernel_cache_dir})", file=sys.stderr, flush=True)

    _warp_setup.on_first_compile(notify)


class _CtrlC:
    """SIGINT raises KeyboardInterrupt (as Python's default handler does) and also arms a timer that
    ends the process with one line and status 130 if it is still running EXIT_GRACE_SECONDS later:
    a KeyboardInterrupt raised while the main thread runs a callback from native code (a threaded
    Warp launch on torch's OpenMP team) is printed and dropped by ctypes, and the command would go
    on. Restores the previous handler on exit."""

    def __init__(self, prog: str):
        self.prog, self.reported, self.old = prog, False, None

    def _handler(self, signum, frame):
        timer = threading.Timer(EXIT_GRACE_SECONDS, self._force_exit)
        timer.daemon = True
        timer.start()
        raise KeyboardInterrupt

    def _force_exit(self):
        if not self.reported:
            print(f"{self.prog}: interrupted", file=sys.stderr, flush=True)
        os._exit(INTERRUPTED_STATUS)

    def __enter__(self):
        if threading.current_thread() is threading.main_thread():
            self.old = signal.signal(signal.SIGINT, self._handler)
        return self

    def __exit__(self, *exc):
        if self.old is not None:
            signal.signal(signal.SIGINT, self.old)
        return False


def _clear_unhandled_interrupt() -> bool:
    """After a handled Ctrl-C: clear CPython's process-wide ``_Py_UnhandledKeyboardInterrupt``.

    CPython 3.10/3.11 set that flag whenever a nested evaluation of code ends with a
    KeyboardInterrupt, even one that is caught further out (as here), and at exit a set flag makes
    the interpreter kill itself with SIGINT (status -2) whatever ``sys.exit`` was given: the one
    line was printed but the status was -2 (measured: the flag was 1 after every interrupted
    ``align``). Later CPythons keep it in private runtime state; there this does nothing and
    returns False (tests/cli/test_cli.py runs the real Ctrl-C and checks the status).
    """
    try:
        flag = ctypes.c_int.in_dll(ctypes.pythonapi, "_Py_UnhandledKeyboardInterrupt")
    except (ValueError, AttributeError, OSError):
        return False
    flag.value = 0
    return True


def run_command(parser: argparse.ArgumentParser, args: argparse.Namespace, requires: Iterable[str] = ()) -> int:
    """Run ``args.func(args)``: the packages in ``requires`` are checked first (one line, status 1,
    if one is missing); a ``UsageError`` is printed after the usage line (status 2); an OSError
    naming a file (one the command cannot make, read or write) and an ``InputError`` (a file it
    cannot use) are one line, status 1; Ctrl-C ends
    the command with one line and status 130."""
    missing = missing_packages(requires)
    if missing:
        hints = "; ".join(INSTALL_HINTS.get(n, f"{n}, which is not installed") for n in missing)
        print(f"{parser.prog}: error: this command needs {hints}", file=sys.stderr)
        return 1
    ctrl_c = _CtrlC(parser.prog)
    try:
        with ctrl_c:
            announce_compiles()
            return args.func(args)
    except UsageError as e:
        parser.error(str(e))
    except InputError as e:  # a file that cannot be used (a data error, not the arguments'): one line
        print(f"{parser.prog}: error: {e}", file=sys.stderr)
        return 1
    except OSError as e:
        if e.filename is None:  # not about a file: a bug or the system's, with its traceback
            raise
        # a file or folder the command cannot make, read or write (e.g. --out on a read-only disk)
        print(f"{parser.prog}: error: {e.filename}: {e.strerror or e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        ctrl_c.reported = True
        print(f"{parser.prog}: interrupted", file=sys.stderr, flush=True)
        _clear_unhandled_interrupt()
        return INTERRUPTED_STATUS
    finally:
        # the notice is the command's, not of later library use in this process (looked up at call
        # time: tests replace it)
        _warp_setup.cancel_first_compile()


def add_command(subparsers, add_parser: Callable, requires: Iterable[str] = ()) -> argparse.ArgumentParser:
    """The parser of one command: made by the command's ``add_parser(subparsers)``, its help tidied
    (:func:`tidy_parser`), and knowing itself and the packages the command needs (``requires``), which
    :func:`parse_and_run` reads back from the parsed arguments."""
    p = tidy_parser(add_parser(subparsers))
    p.set_defaults(_parser=p, _requires=tuple(requires))
    return p


def parse_and_run(parser: argparse.ArgumentParser, argv: list[str] | None) -> int:
    """Parse ``argv`` with ``parser`` and run the command the arguments name (:func:`run_command`
    with the command's parser and packages, set by :func:`add_command`). Ctrl-C while parsing is one
    line and status 130; Ctrl-C again while ``run_command`` cleans up after reporting one is still
    status 130, not Python's exit for an unhandled KeyboardInterrupt (killed by SIGINT, status -2).
    ``argv`` None: the program's own arguments (``sys.argv[1:]``), and :func:`freeze_at_exit`."""
    if argv is None:
        freeze_at_exit()
    try:
        args, extras = parser.parse_known_args(argv)
        if extras:  # (refused by the command's own parser: its usage, not the program's, unless they
            # come before the command's name)
            given = sys.argv[1:] if argv is None else list(argv)
            command = getattr(args, "command", None)
            before = given[:given.index(command)] if command in given else []
            owner = parser if any(e in before for e in extras) else getattr(args, "_parser", parser)
            owner.error(f"unrecognized arguments: {' '.join(extras)}")
    except KeyboardInterrupt:
        print(f"{parser.prog}: interrupted", file=sys.stderr)
        return INTERRUPTED_STATUS
    try:
        return run_command(args._parser, args, args._requires)
    except KeyboardInterrupt:
        _clear_unhandled_interrupt()
        return INTERRUPTED_STATUS


def freeze_at_exit() -> None:
    """At exit, freeze every object before Python's last garbage collections (``gc.freeze``: they skip
    frozen objects). Those collections walk every object the process still holds, ~1 s once torch
    is imported, and find nothing a command needs: its files are written and closed by then. The exit
    handlers, module teardown and reference counting still run; what is lost is the finalisation of
    objects caught in reference cycles (their ``__del__``), which no command relies on. Called by
    :func:`parse_and_run` when a command runs as a program (``gvnn-warp``, ``python -m
    gvnn_warp.cli.<command>``: ``argv`` None), not when ``main`` is called with arguments from other
    code; once per process."""
    atexit.unregister(gc.freeze)
    atexit.register(gc.freeze)


def command_main(add_parser: Callable, requires: Iterable[str] = (), argv: list[str] | None = None) -> int:
    """One command run on its own (``python -m gvnn_warp.cli.<command> ...``, e.g. under torchrun):
    the same parser, checks and handling as ``gvnn-warp <command> ...``; ``argv`` defaults to
    ``sys.argv[1:]``."""
    root = argparse.ArgumentParser(prog="gvnn-warp")
    parser = add_command(root.add_subparsers(), add_parser, requires)
    return parse_and_run(parser, argv)
