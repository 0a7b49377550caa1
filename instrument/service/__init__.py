"""The REST service: the FastAPI application, its routes, request schemas, RFC 9457 problems,
settings, uploads, the measurement store and the web page.

:mod:`.app` builds the application; the routes share :mod:`.state`. It may import
:mod:`..inference`, :mod:`..tables`, :mod:`..plotting`, and :mod:`solitonde.signal` /
:mod:`solitonde.model`; never the command line or the studies.
"""
