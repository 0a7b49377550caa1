"""solitonde.instrument: the application around the physics.

Sub-packages, by concern (each one's docstring says what it may import):

- :mod:`.cli`: the ``solitonde`` command line;
- :mod:`.service`: the REST service, its store and web page;
- :mod:`.tables`: model tables, their build and the plate-response cache;
- :mod:`.inference`: inversion, calibration, table choice, plate maps;
- :mod:`.studies`: reproduction of the paper, accuracy against cost, validation;
- :mod:`.plotting`: PNG figures of traces and maps, shared by the others.

Their layers and the absence of import cycles are import-linter contracts in pyproject.toml
(``tests/test_import_contracts.py``); the layer's error base is :mod:`.errors`.
"""

from solitonde.model.jit_cache import configure as _configure_jit_cache

_configure_jit_cache()  # the kernels' cache follows the source (see solitonde.model.jit_cache)
