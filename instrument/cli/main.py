"""The `solitonde` command line: one Typer app assembled from one module per command.

Each ``cmd_*.py`` module in this folder defines ``register(app)`` that adds its commands; list
it in :data:`COMMANDS` with its one-line help to make it part of the CLI.

The console script loads only what a call needs: ``solitonde theory ...`` imports the theory
command's module and nothing of the others (no numba kernels, no scipy.stats, no pandas), and
``solitonde --help`` or ``--version`` imports none of them, listing the commands from
:data:`COMMANDS` (a test holds that list to the commands' own help). :func:`build_app` assembles
everything, for tests and for a name that is no command (Click then suggests the nearest).
"""

from __future__ import annotations

import importlib
import sys
from typing import Any

import typer

COMMANDS: dict[str, tuple[str, str]] = {
    "analyze": ("cmd_analyze", "Measure TOF, ARR, SNR and quality flags of every shot; aggregate "
                               "per position."),
    "samples": ("cmd_samples", "Regenerate the synthetic sample waveforms and their truth table "
                               "(data_samples/waveforms/), or with --scan the simulated scan of a "
                               "plate near its clamped edge (data_samples/scan/)."),
    "simulate": ("cmd_simulate", "Simulate one shot (striker, chain, plate) and report TOF, ARR "
                                 "and diagnostics."),
    "theory": ("cmd_theory", "Closed-form predictions (Zener impact, ARR, TOF, critical "
                             "distance) for a scene."),
    "post": ("cmd_post", "Upload waveform files to the service; each is stored once (a repeat "
                         "is a replay)."),
    "watch": ("cmd_watch", "Post every new waveform file in a folder once it is complete; a "
                           "queue on disk survives outages and restarts."),
    "serve": ("cmd_serve", "Start the REST service (OpenAPI docs at /docs); Ctrl-C stops it "
                           "cleanly."),
    "invert": ("cmd_invert", "Estimate plate thickness and distance to the nearest support from "
                             "TOF and ARR."),
    "map": ("cmd_map", "Map a plate: thickness and distance to support at each position, the "
                       "support located."),
    "calibrate": ("cmd_calibrate", "Fit the chain's damping (with a table's dissipation layer), "
                                   "ARR factor and TOF offset per sphere size on a reference "
                                   "plate; write them as JSON."),
    "validate": ("cmd_validate", "Simulate random plates with noise and dissipation, invert, and "
                                 "score the answers."),
    "validate-map": ("cmd_validate_map", "Simulate scans of random plates, invert them jointly "
                                         "and one by one, and score both."),
    "reproduce": ("cmd_reproduce", "Regenerate the paper's figures 3-10 (PNG + CSV each) and "
                                   "summary.json with the checks."),
    "table": ("cmd_table", "Build and inspect model tables."),
    "bench": ("cmd_bench", "Benchmarks of the model."),
    "cache": ("cmd_cache", "What the plate-response store and the compiled-code cache hold; "
                           "clear them."),
    "store": ("cmd_store", "Back up, check, migrate and reanalyze a measurement store."),
    "setup": ("cmd_setup", "Instrument set-ups kept by a service: create, show, list, "
                           "calibrate."),
    "report": ("cmd_report", "Inspection reports: build one (PDF, HTML or its JSON) and verify "
                             "one against the stored data."),
}
"""Every command: the module that registers it and its one-line help, in the order listed."""

HELP_MARKUP = None
"""Click's plain help: option names with NUMBER / PATH / TEXT metavars, flags without one, wrapped
to the terminal (typer's rich panels print raw labels such as ``<bool>`` and ``<list[str]>``)."""

HELP = "Plate NDE with highly nonlinear solitary waves: theory, simulation, analysis, service."


_LABELS = {"str": "TEXT", "int": "INTEGER", "float": "NUMBER", "path": "PATH", "Path": "PATH",
           "file": "FILE", "dir": "DIR", "int range": "INTEGER", "float range": "NUMBER"}


def _conventional_labels() -> None:
    """Help shows value types as Click always did (``--port INTEGER``, ``--out PATH``, a flag
    with no label) instead of typer's raw ``<int range>``, ``<list[Path]>``, ``<bool>``. Typer
    offers no setting for it, so its one label method is wrapped; unknown labels pass through."""
    from typer.core import TyperArgument, TyperOption

    for cls in (TyperOption, TyperArgument):
        raw = cls.display_type
        if getattr(raw, "_solitonde", False):
            continue

        def display_type(self: Any, ctx: Any, _raw: Any = raw) -> str | None:
            if getattr(self, "is_flag", False):
                return None
            label = _raw(self, ctx)
            inner = label[1:-1] if label.startswith("<") and label.endswith(">") else label
            if inner.startswith("list[") and inner.endswith("]"):
                inner = inner[5:-1]
            if "|" in inner:
                return f"[{inner}]"
            return _LABELS.get(inner, inner.upper())

        display_type._solitonde = True  # type: ignore[attr-defined]
        cls.display_type = display_type  # type: ignore[method-assign,assignment]


def _version(value: bool) -> None:
    if value:
        from solitonde.model.version import UNKNOWN, package_version

        found = package_version()
        typer.echo("solitonde (not installed)" if found == UNKNOWN else f"solitonde {found}")
        raise typer.Exit()


def _root(
    _show_version: bool = typer.Option(False, "--version", callback=_version, is_eager=True,
                                       help="Print the version and exit."),
) -> None:
    """Plate NDE with highly nonlinear solitary waves: theory, simulation, analysis, service."""
    # A callback keeps `solitonde <command>` a group even while only one command is registered.


def new_app() -> typer.Typer:
    """An empty `solitonde` app: the name, the help, ``--version``, shell completion."""
    _conventional_labels()
    app = typer.Typer(name="solitonde", help=HELP, no_args_is_help=True,
                      pretty_exceptions_enable=False, rich_markup_mode=HELP_MARKUP)
    app.callback()(_root)
    return app


app = new_app()


def build_app() -> typer.Typer:
    """Attach every command module's commands to the app (idempotent)."""
    if not getattr(app, "_solitonde_registered", False):
        for module, _help in COMMANDS.values():
            importlib.import_module(f"solitonde.instrument.cli.{module}").register(app)
        app._solitonde_registered = True  # type: ignore[attr-defined]
    return app


def app_for(args: list[str]) -> typer.Typer:
    """The smallest app that answers ``solitonde ARGS``: one command's module, or the listing."""
    name = next((a for a in args if not a.startswith("-")), None)
    if name in COMMANDS:
        one = new_app()
        importlib.import_module(f"solitonde.instrument.cli.{COMMANDS[name][0]}").register(one)
        return one
    if name is None:  # --help, --version, completion, or nothing: the listing is enough
        listing = new_app()
        for command, (_module, text) in COMMANDS.items():
            listing.command(command, help=text)(_listed)
        return listing
    return build_app()


def _listed() -> None:
    """Stands for a command in the listing; never run (a command's name loads its module)."""
    raise RuntimeError("a listed command was run without its module")


def main() -> None:
    """Console-script entry point."""
    app_for(sys.argv[1:])()


if __name__ == "__main__":
    main()
