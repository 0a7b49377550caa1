"""The model table: the file (:mod:`.table`), its parallel, resumable build
(:mod:`.table_build`), the plate family it holds for (:mod:`.family`) and the on-disk cache of
plate responses (:mod:`.greens_cache`).

It imports only :mod:`solitonde.model` and :mod:`solitonde.signal`.
"""
