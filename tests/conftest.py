"""Test-session set-up: numba's cache folder follows the source of the kernels
(:mod:`solitonde.model.jit_cache`), also in a run of test files that import only
``solitonde.signal`` modules (which have no package ``__init__`` to set it); the extractor is
compiled before a command's first shot (:mod:`solitonde.signal.kernel_choice`)."""

import atexit
import os
import shutil
import tempfile

from solitonde.model.jit_cache import configure
from solitonde.signal.kernel_choice import COMPILE_FIRST_ENV

configure()
# Commands run in-process (CliRunner) or as child processes compile the extractor before their
# first shot, as a library call does: no test's numbers depend on whether a background compile
# started by another test has finished. tests/signal/test_precompile.py unsets it where it tests
# the interpreted start.
os.environ[COMPILE_FIRST_ENV] = "1"

# Table builds keep plate responses in an on-disk store (solitonde.instrument.tables.greens_cache):
# this session's go to a folder of its own, never the user's (even one SOLITONDE_CACHE names),
# and are removed at the end.
_responses = tempfile.mkdtemp(prefix="solitonde-test-responses-")
os.environ["SOLITONDE_CACHE"] = _responses
atexit.register(shutil.rmtree, _responses, ignore_errors=True)
