"""Test-session set-up: numba's cache folder follows the source of the kernels
(:mod:`solitonde.model.jit_cache`), also in a run of test files that import only
``solitonde.signal`` modules (which have no package ``__init__`` to set it)."""

from solitonde.model.jit_cache import configure

configure()
