"""The model table: the file (:mod:`.table`), what a table covers (:mod:`.sweep`), its parallel,
resumable build (:mod:`.table_build`, the file while it is built: :mod:`.table_file`), the
plate family it holds for (:mod:`.family`) and the on-disk cache of plate responses
(:mod:`.greens_cache`).

It imports :mod:`solitonde.model`, :mod:`solitonde.signal` and, of the instrument, only its errors
and its executor (:mod:`solitonde.instrument.parallel`).
"""
