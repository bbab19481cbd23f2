"""The test helper that reads a server CLI's output: a process that hangs before printing what a test waits
for fails the test within its deadline, with the process's stacks, instead of holding the test run."""

from __future__ import annotations

import subprocess
import sys

import pytest
from _helpers import OutputLines


def _python(code: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, env={"PYTHONFAULTHANDLER": "1", "PYTHONUNBUFFERED": "1"})


def test_a_hang_before_the_line_fails_in_time_with_the_stack():
    proc = _python("import time\nprint('starting')\ntime.sleep(600)")
    with pytest.raises(AssertionError) as e:
        OutputLines(proc).wait_for("serving", timeout=2)
    text = str(e.value)
    assert "within 2 s" in text and "starting" in text and 'File "<string>", line 3' in text
    assert proc.poll() is not None


def test_an_early_exit_fails_and_a_served_line_returns_its_match_and_the_rest():
    with pytest.raises(AssertionError, match=r"ended \(3\) before printing"):
        OutputLines(_python("print('oops'); raise SystemExit(3)")).wait_for("serving", timeout=60)
    out = OutputLines(_python("print('a'); print('serving at http://x:5'); print('refused GET /')"))
    assert out.wait_for(r"serving at (\S+)", timeout=60).group(1) == "http://x:5"
    assert out.rest(timeout=60) == "refused GET /\n" and out.lines[0] == "a\n"
