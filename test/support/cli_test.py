"""What the command-line tests (test/*/*_test.py) share: running a command and
reading its exit status and output, checks that end the test on the first
failure and checks that are tallied to the end, a fresh work folder, a script
loaded as a module, and a free TCP port.

ctest runs the tests as plain scripts, under /usr/bin/python3 or (for
test/scripts/test_convert_roundtrip.py) the Python with PyTorch, so this is
the standard library only, Python 3.7 and later. A test imports it by its
path:

    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "support"))
    import cli_test
"""
import importlib.util
import os
import shutil
import socket
import subprocess
import sys


def fail(what):
    """Ends the test: prints "FAIL: <what>" and exits 1."""
    print("FAIL:", what)
    sys.exit(1)


def check(cond, what):
    """Ends the test (fail) unless cond holds."""
    if not cond:
        fail(what)


class Tally:
    """Checks that do not end the test: each prints a line, `ok` or `failed`
    followed by what it checks, and the failed ones are kept in `failures`
    for the end of the test."""

    def __init__(self, ok="ok   ", failed="FAIL "):
        self._ok = ok
        self._failed = failed
        self.failures = []

    def check(self, cond, what):
        """Prints the line; returns cond."""
        print("%s%s" % (self._ok if cond else self._failed, what))
        if not cond:
            self.failures.append(what)
        return cond

    @property
    def passed(self):
        return not self.failures


def run_process(cmd, env=None, cwd=None, timeout=None, merge_output=False, expect_rc=None):
    """Runs cmd (a list of words) to its end and returns its
    subprocess.CompletedProcess, stdout and stderr as text (with merge_output,
    stdout holds both as they were written and stderr is None). When
    expect_rc is given and the exit status differs, prints the command, the
    status and the last 2000 characters of each stream. A run past timeout
    seconds raises subprocess.TimeoutExpired."""
    p = subprocess.run(cmd, stdout=subprocess.PIPE,
                       stderr=subprocess.STDOUT if merge_output else subprocess.PIPE,
                       universal_newlines=True, env=env, cwd=cwd, timeout=timeout)
    if expect_rc is not None and p.returncode != expect_rc:
        print("command %s exited %d (expected %d)\nstdout: %s\nstderr: %s"
              % (cmd, p.returncode, expect_rc, p.stdout[-2000:], (p.stderr or "")[-2000:]))
    return p


def run(cmd, env=None, cwd=None, timeout=None, merge_output=False, check=False):
    """Runs cmd (run_process) and returns (exit status, output): stdout
    followed by stderr, or with merge_output the two interleaved as written.
    With check, a non-zero exit status ends the test (fail), naming the
    command and showing its output."""
    p = run_process(cmd, env=env, cwd=cwd, timeout=timeout, merge_output=merge_output)
    output = p.stdout if merge_output else p.stdout + p.stderr
    if check and p.returncode != 0:
        fail("%s exited %d:\n%s" % (" ".join(str(w) for w in cmd), p.returncode, output))
    return p.returncode, output


def fresh_dir(path):
    """An empty folder at path (removed first with all it holds); returns path."""
    shutil.rmtree(path, ignore_errors=True)
    os.makedirs(path)
    return path


def load_script(path, name):
    """The Python file at path (e.g. one of scripts/) as a module named name."""
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def free_port(host="127.0.0.1"):
    """A TCP port on host that nothing listens on at the moment."""
    with socket.socket() as s:
        s.bind((host, 0))
        return s.getsockname()[1]
