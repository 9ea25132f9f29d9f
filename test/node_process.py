"""Helpers for tests that run the node as a separate process, as users do."""
import subprocess

import pytest


def finish(process, timeout=120.0):
    """(exit code, stdout, stderr) once the node has exited on its own; fail if it hangs."""
    try:
        out, err = process.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        process.kill()
        out, err = process.communicate()
        pytest.fail(f'the node did not exit within {timeout} s: {err[-2000:]}')
    return process.returncode, out, err
