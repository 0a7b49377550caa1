# The two set-up-inclusive commands (README): `make run` and `make test`.
# Both create .venv on first use and reinstall only when pyproject.toml changes.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# `make run PORT=8001 HOST=0.0.0.0`: passed to `solitonde serve`, which refuses a non-loopback
# HOST unless SOLITONDE_API_KEY is set (or --insecure is given to it directly).
HOST ?= 127.0.0.1
PORT ?= 8000

.PHONY: run test lint bench report-figures clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

run: $(STAMP)
	$(BIN)/solitonde serve --host '$(HOST)' --port '$(PORT)' --table data_samples/default_table.h5

# The tests run on TEST_WORKERS processes (pytest-xdist), a test file per process at a time
# (module fixtures are built once); TEST_WORKERS=0 runs them in this one.
TEST_WORKERS ?= 2

test: $(STAMP)
	$(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadfile

lint: $(STAMP)
	$(BIN)/ruff check .

bench: $(STAMP)
	$(BIN)/python -m pytest -q -m bench -s

# The bundled scan's inspection report (PDF, HTML) and its first pages as images, beside the
# other figures: built from the recordings, as `report build --manifest` builds any.
FIGURES := data_samples/figures
report-figures: $(STAMP)
	$(BIN)/solitonde report build --manifest data_samples/scan/campaign.csv --plate-id SCAN-A --out $(FIGURES)/scan_report.pdf
	$(BIN)/solitonde report build --manifest data_samples/scan/campaign.csv --plate-id SCAN-A --out $(FIGURES)/scan_report.html
	$(BIN)/python -c "import pypdfium2 as p; d = p.PdfDocument('$(FIGURES)/scan_report.pdf'); [d[i].render(scale=1.5).to_pil().save(f'$(FIGURES)/scan_report_page{i + 1}.png') for i in range(2)]"

clean:
	rm -rf $(VENV) build *.egg-info
