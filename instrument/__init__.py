"""solitonde.instrument: the application (CLI, model table, inversion, REST service, store)."""
