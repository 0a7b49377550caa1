"""From measured shots to estimates: the measured-shot road (:mod:`.measured_shots`: read, check
metadata, group by position, summarise), the Bayesian inversion against a table
(:mod:`.inversion`), calibration (:mod:`.calibration`, :mod:`.calibration_fit`), choosing among
loaded tables (:mod:`.table_set`, :mod:`.estimates`), plate maps and the located support
(:mod:`.plate_map`, :mod:`.support`), and estimate rows for files (:mod:`.estimate_rows`).

It may import :mod:`..tables` and :mod:`solitonde.signal` / :mod:`solitonde.model`; never the
service, the command line or the studies.
"""
