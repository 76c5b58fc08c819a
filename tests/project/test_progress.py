"""Progress output: a bar on a terminal, whole lines (no carriage returns) in a log or a pipe."""

import io
import subprocess
import sys

from gvnn_warp.progress import LineProgress, progress_bar


class _Terminal(io.StringIO):
    def isatty(self):
        return True


def test_a_log_gets_lines_and_a_terminal_a_bar():
    log = io.StringIO()
    with progress_bar(total=3, desc="work", file=log) as bar:
        assert isinstance(bar, LineProgress) and bar.mininterval >= 10
        for _ in range(3):
            bar.update()
    text = log.getvalue()
    assert "\r" not in text and text.endswith("\n") and "work" in text and "3/3" in text.splitlines()[-1]
    term = _Terminal()
    with progress_bar(total=3, desc="work", file=term) as bar:
        assert not isinstance(bar, LineProgress)
        bar.update(3)
    assert "\r" in term.getvalue()
    assert progress_bar(total=3, disable=True, file=log).disable


def test_a_command_piped_to_a_file_writes_no_carriage_returns(tmp_path):
    run = subprocess.run([sys.executable, "-m", "gvnn_warp", "render", "--out", str(tmp_path / "seq"), "--frames",
                          "3", "--size", "32x24"], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert "\r" not in run.stderr and "render" in run.stderr
