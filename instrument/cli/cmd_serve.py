"""``solitonde serve``: run the REST service under uvicorn."""

from __future__ import annotations

import os
import shlex
import signal
from pathlib import Path

import typer

from solitonde.instrument.service.settings import (
    DEFAULT_STORE,
    DEFAULT_TABLE,
    Settings,
    SettingsError,
)
from solitonde.instrument.tables.bundled import sample_waveforms

SAMPLE_EXTENSIONS = ("csv", "npy", "h5", "tdms")


def sample_file(root: Path | None = None) -> Path | None:
    """A bundled sample waveform file to show in the curl example (CSV preferred).

    Relative to the working directory when it holds the samples (the README's `make run`), else
    the absolute path of the package's own copy, so the printed command works from anywhere.
    """
    folders = [root / "data_samples" / "waveforms"] if root is not None else [
        Path("data_samples") / "waveforms", sample_waveforms()]
    for folder in folders:
        for ext in SAMPLE_EXTENSIONS:
            for path in sorted(folder.glob(f"*.{ext}")):
                if path.is_file():
                    return path
    return None


def curl_example(url: str, api_key_set: bool, sample: Path | None) -> str:
    """One curl command that posts a sample file to the running service."""
    parts = ["curl", "-sS"]
    if api_key_set:
        parts += ["-H", '"X-API-Key: $SOLITONDE_API_KEY"']
    file_arg = f"file=@{sample}" if sample else "file=@YOUR_SHOT.csv"
    parts += ["-F", shlex.quote(file_arg), f"{url}/v1/measurements"]
    return " ".join(parts)


def register(app: typer.Typer) -> None:
    @app.command()
    def serve(
        host: str = typer.Option("127.0.0.1", help="address to bind (loopback by default)"),
        port: int = typer.Option(8000, min=1, max=65535, help="TCP port"),
        workers: int = typer.Option(1, min=1, max=64, help="uvicorn worker processes"),
        table: list[Path] = typer.Option(
            [], help=f"model table for estimates, or a folder of them; repeat for several plate "
                     f"families (default: $SOLITONDE_TABLE, else {DEFAULT_TABLE} when it "
                     "exists; without one, no estimates)"),
        store: Path | None = typer.Option(
            None, help=f"SQLite measurement store (default: $SOLITONDE_STORE, else "
                       f"{DEFAULT_STORE})"),
        log_level: str = typer.Option("info", help="uvicorn log level"),
        insecure: bool = typer.Option(False, "--insecure", help="serve a non-loopback address "
                                      "without SOLITONDE_API_KEY (anyone who reaches it can "
                                      "write and read measurements)"),
    ) -> None:
        """Start the REST service (OpenAPI docs at /docs); Ctrl-C stops it cleanly."""
        import uvicorn

        env_table = os.environ.get("SOLITONDE_TABLE") or None
        table_path = table[0] if table else (Path(env_table) if env_table else None)
        if table_path is None and DEFAULT_TABLE.is_file():
            table_path = DEFAULT_TABLE
        try:
            settings = Settings.from_env(host=host, port=port, table_path=table_path,
                                         store_path=store,
                                         table_paths=tuple(table[1:]) if table else None)
        except SettingsError as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(2) from None
        from solitonde.instrument.service.store import Store, StoreError

        try:  # a store that cannot be used is one line here, not a traceback from each worker
            Store(settings.store_path, settings.store_synchronous,
                  background_checkpoint=False).close()
        except StoreError as exc:
            typer.echo(f"error: store: {exc}", err=True)
            raise typer.Exit(2) from None
        given = [p for p in (settings.table_path, *settings.table_paths) if p is not None]
        for p in given[1:]:
            if not p.exists():
                typer.echo(f"error: --table: no such file or folder: {p}", err=True)
                raise typer.Exit(2)
        from solitonde.signal import kernel_choice

        # A fresh install compiles the feature extractor in the background and answers the
        # first shots interpreted meanwhile. Several workers would each run the interpreted
        # kernels: wait for the compile here, first.
        kernel_choice.start()
        if workers > 1:
            kernel_choice.finish()
        if not given or not given[0].exists():
            where = settings.table_path or DEFAULT_TABLE
            typer.echo(f"warning: no model table at {where}: serving without estimates "
                       "(measurements come back with \"estimate\": null)", err=True)
        if host not in ("127.0.0.1", "localhost", "::1"):
            if settings.api_key is None and not insecure:
                typer.echo(f"error: --host {host}: other machines could reach the service and "
                           "SOLITONDE_API_KEY is not set; set a key (16 characters or more), or "
                           "pass --insecure to serve without one", err=True)
                raise typer.Exit(2)
            typer.echo(f"warning: binding {host}: the service is reachable from other "
                       "machines" + ("" if settings.api_key else
                                     " and SOLITONDE_API_KEY is not set (--insecure)"), err=True)
        os.environ.update(settings.to_env())
        shown = f"[{host}]" if ":" in host else host
        url = f"http://{shown}:{port}"
        typer.echo(f"solitonde service on {url}  (docs: {url}/docs, store: "
                   f"{settings.store_path}, workers: {workers})")
        typer.echo("try:  " + curl_example(url, settings.api_key is not None, sample_file()))
        # uvicorn shuts down gracefully on SIGINT and SIGTERM, restores the previous handlers
        # and re-raises the signal; with these handlers a clean stop exits with status 0.
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, _exit_cleanly)
        uvicorn.run("solitonde.instrument.service.app:build_app_from_env", factory=True, host=host,
                    port=port, workers=workers, log_level=log_level, access_log=False)


def _exit_cleanly(signum: int, frame: object) -> None:
    raise SystemExit(0)
