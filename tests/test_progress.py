"""The progress display (output/progress.py): silent unless stderr is a terminal and not
--quiet; the seconds before the first frames say what they are spent on."""

import io
import sys

from taichi_cloth.output.progress import Progress, announce


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_a_terminal_hears_what_the_run_waits_for(monkeypatch):
    terminal = Terminal()
    monkeypatch.setattr(sys, "stderr", terminal)
    announce("hula", "settling on the still body", quiet=False)
    with Progress("hula", 3, quiet=False) as progress:
        assert "compiling the step's kernels" in terminal.getvalue()
        progress.update(0.0)
        progress.update(1 / 30)
    text = terminal.getvalue()
    assert text.startswith("hula: settling on the still body\n")
    assert "t = 0.03 s" in text.replace("\r", "\n")


def test_quiet_or_a_pipe_hears_nothing(monkeypatch):
    for stream, quiet in ((Terminal(), True), (io.StringIO(), False)):
        monkeypatch.setattr(sys, "stderr", stream)
        announce("hula", "settling", quiet)
        with Progress("hula", 2, quiet) as progress:
            progress.update(0.0)
        assert stream.getvalue() == ""
