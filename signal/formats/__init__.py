"""Waveform file formats as plug-ins: one module per format, each declaring a
:class:`~.base.FileFormat`, listed once in :mod:`.registry` (read and written through
:mod:`solitonde.signal.io`)."""
