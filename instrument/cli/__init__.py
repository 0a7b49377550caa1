"""The command line: ``solitonde`` and one module per command (``cmd_*.py``).

:mod:`.main` assembles the Typer app and loads a command's module only when it is called. The
commands turn flags and files into calls of the other sub-packages and print or write the
answers; they may import every other part of :mod:`solitonde.instrument`, and nothing imports
them.
"""
