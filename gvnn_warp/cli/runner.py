"""The gvnn-warp command line: demos of the layers on data made at run time.

Every command checks its arguments before it starts (a bad one gets a one-line error after the
usage line and exit status 2), checks that the packages it needs are installed, and exits with one
line and status 130 on Ctrl-C.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import os
import signal
import sys
import threading

from .args import HelpFormatter, UsageError, plain_text

# subcommand modules in gvnn_warp.demos; each has add_parser(subparsers), its own run(args), and
# optionally REQUIRES: the importable packages it needs, checked before it starts
DEMOS = ("align", "flow", "vo", "render", "track")

# what to tell a user who lacks a package a command needs
INSTALL_HINTS = {
    "torch": "PyTorch, which is not installed: pip install 'gvnn_warp[torch]' (for the CPU-only build, first: "
    "pip install torch --index-url https://download.pytorch.org/whl/cpu)",
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


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="gvnn-warp", description=__doc__.split("\n\n")[0], formatter_class=HelpFormatter
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in DEMOS:
        module = importlib.import_module(f"gvnn_warp.cli.{name}")
        module.add_parser(sub)
        p = tidy_parser(sub.choices[name])
        p.set_defaults(_parser=p, _requires=tuple(getattr(module, "REQUIRES", ())))
    for action in sub._choices_actions:  # the one-line summaries in `gvnn-warp --help`
        action.help = plain_text(action.help)
    return parser


def missing_packages(names) -> list[str]:
    return [n for n in names if importlib.util.find_spec(n) is None]


def announce_compiles() -> None:
    """Print one line on stderr before Warp first compiles a kernel module in this process (a
    cold kernel cache: the first run, or a new gvnn_warp or Warp version); nothing when every
    module comes from the cache. Only rank 0 prints under torchrun."""
    from .._warp_setup import on_first_compile

    if os.environ.get("RANK", "0") != "0":
        return
    import warp as wp

    def notify():
        print(f"gvnn-warp: compiling kernels, once (a few seconds per module; cached in "
              f"{wp.config.kernel_cache_dir})", file=sys.stderr, flush=True)

    on_first_compile(notify)


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
    returns False (tests/test_cli.py runs the real Ctrl-C and checks the status).
    """
    try:
        import ctypes

        flag = ctypes.c_int.in_dll(ctypes.pythonapi, "_Py_UnhandledKeyboardInterrupt")
    except (ImportError, ValueError, AttributeError, OSError):
        return False
    flag.value = 0
    return True


def run_command(parser: argparse.ArgumentParser, args: argparse.Namespace, requires=()) -> int:
    """Run ``args.func(args)``: the packages in ``requires`` are checked first (one line, status 1,
    if one is missing); a ``UsageError`` is printed after the usage line (status 2); an OSError
    naming a file (one the command cannot make, read or write) is one line, status 1; Ctrl-C ends
    the command with one line and status 130."""
    missing = missing_packages(requires)
    if missing:
        hints = "; ".join(INSTALL_HINTS.get(n, f"{n}, which is not installed") for n in missing)
        print(f"{parser.prog}: error: this command needs {hints}", file=sys.stderr)
        return 1
    from .._warp_setup import cancel_first_compile

    ctrl_c = _CtrlC(parser.prog)
    try:
        with ctrl_c:
            announce_compiles()
            return args.func(args)
    except UsageError as e:
        parser.error(str(e))
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
        cancel_first_compile()  # the notice is the command's, not of later library use in this process


def main(argv: list[str] | None = None) -> int:
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
    except KeyboardInterrupt:
        print("gvnn-warp: interrupted", file=sys.stderr)
        return INTERRUPTED_STATUS
    try:
        return run_command(args._parser, args, args._requires)
    except KeyboardInterrupt:
        # raised again while run_command cleaned up after reporting one: still the one line and 130,
        # not Python's exit for an unhandled KeyboardInterrupt (killed by SIGINT, status -2)
        _clear_unhandled_interrupt()
        return INTERRUPTED_STATUS

