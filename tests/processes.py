"""Python code run in a process of its own, for the tests that need a fresh interpreter (what is
imported or defined on first use, threads, signals, environment variables)."""

import subprocess
import sys

# Prepended to every script: the process freezes its objects at exit, so that Python's last garbage
# collections skip them (~1 s once torch is imported), as every gvnn-warp command does
# (gvnn_warp.cli.runner.freeze_at_exit). atexit and gc are built in: nothing else is imported.
FAST_EXIT = "import atexit, gc; atexit.register(gc.freeze)\n"


def run_python(code: str, *args: str, python=sys.executable, **kwargs) -> subprocess.CompletedProcess:
    """``subprocess.run([python, "-c", code, *args], **kwargs)`` with :data:`FAST_EXIT` first; output
    captured as text unless ``kwargs`` say otherwise."""
    if "stdout" not in kwargs and "stderr" not in kwargs:
        kwargs.setdefault("capture_output", True)
    kwargs.setdefault("text", True)
    return subprocess.run([str(python), "-c", FAST_EXIT + code, *map(str, args)], **kwargs)
