"""A report as HTML (Jinja2) and as PDF (the same HTML through WeasyPrint), standing alone.

The figures are PNGs embedded as data URIs and the fonts are the system's free ones (DejaVu,
Liberation), which WeasyPrint embeds in the PDF: neither file makes a request of its own. The
report's data (``report.json``, :mod:`.content`) travel inside: attached to the PDF as a file,
and in the HTML as a ``<script type="application/json" id="report-data">`` block, so ``report
verify`` reads either.
"""

from __future__ import annotations

import base64
import json
from collections.abc import Mapping, Sequence
from importlib import resources
from typing import Any

import jinja2
from markupsafe import Markup

from solitonde.instrument.reports.content import Trace

ATTACHMENT = "report.json"
"""The name of the report's data attached to the PDF."""
DIGESTS_PRINTED = 60
"""Each measurement's digest is printed for up to this many measurements; a longer plate's
are in the attachment only (the overall digest is always printed)."""


def _mm(value: Any, digits: int = 2) -> str:
    return "-" if value is None else f"{float(value) * 1e3:.{digits}f}"


def _answer(p: Mapping[str, Any] | None) -> str:
    """A parameter's answer in mm: median and 95 % interval, or its bound, or its status."""
    if not p:
        return "-"
    ci = p.get("ci95") or [None, None]
    status = p.get("status")
    if status == "constrained" and p.get("median") is not None:
        return f"{_mm(p['median'])} ({_mm(ci[0])}..{_mm(ci[1])})"
    if status == "lower_bound_only":
        return f"at least {_mm(ci[0])}"
    if status == "upper_bound_only":
        return f"at most {_mm(ci[1])}"
    if status == "ambiguous":
        span = f" {_mm(ci[0])}..{_mm(ci[1])}" if ci[0] is not None and ci[1] is not None else ""
        return f"ambiguous{span} (see the readings)"
    return str(status)


def _us(value: Any) -> str:
    return "-" if value is None else f"{float(value) * 1e6:.2f}"


def _fixed(value: Any, digits: int) -> str:
    return "-" if value is None else f"{float(value):.{digits}f}"


def _css_text(value: Any) -> str:
    """Text inside a CSS string: quotes and backslashes escaped, control characters dropped."""
    text = "".join(ch for ch in str(value) if ch.isprintable())
    return text.replace("\\", "\\\\").replace('"', '\\"').replace("<", "\\3C ")


def _environment() -> jinja2.Environment:
    env = jinja2.Environment(
        loader=jinja2.PackageLoader("solitonde.instrument.reports", "templates"),
        autoescape=jinja2.select_autoescape(["html", "j2"]),
        trim_blocks=True, lstrip_blocks=True)
    env.filters.update(mm=_mm, answer=_answer, us=_us, fixed=_fixed, css_text=_css_text)
    return env


def _png_uri(data: bytes) -> str:
    return "data:image/png;base64," + base64.b64encode(data).decode("ascii")


def report_json(report: Mapping[str, Any]) -> str:
    """report.json's text."""
    return json.dumps(report, indent=1, allow_nan=False)


def html(report: Mapping[str, Any], map_png: bytes, traces: Sequence[Trace],
         trace_pngs: Sequence[bytes]) -> str:
    """The report as one standalone HTML document."""
    css = resources.files("solitonde.instrument.reports").joinpath(
        "templates/report.css").read_text(encoding="utf-8")
    data = json.dumps(report, allow_nan=False).replace("<", "\\u003c")  # no tag can close it
    template = _environment().get_template("report.html.j2")
    said = [p.get("warnings") or [] for p in report["positions"]]
    common = [w for w in said[0] if all(w in other for other in said[1:])] if len(said) > 1 \
        else []
    return template.render(common_warnings=common, digests_printed=DIGESTS_PRINTED,
        r=report, css=css, map_png=_png_uri(map_png), data_json=Markup(data),
        traces={(t.measurement_id, t.shot_index): _png_uri(png)
                for t, png in zip(traces, trace_pngs, strict=True)},
        n_shots=sum(len(m["shots_sha256"]) for m in report["measurements"]))


def pdf(document: str, report: Mapping[str, Any]) -> bytes:
    """The HTML as PDF, with report.json attached. WeasyPrint fetches nothing: every resource
    is inline (``data:``), and it is allowed no other protocol."""
    import logging

    import weasyprint

    logging.getLogger("weasyprint").setLevel(logging.ERROR)
    logging.getLogger("fontTools").setLevel(logging.ERROR)

    fetcher = weasyprint.URLFetcher(allowed_protocols=["data"], fail_on_errors=True)
    attachment = weasyprint.Attachment(string=report_json(report), name=ATTACHMENT,
                                       description="the report's data: measurements, results, "
                                       "provenance and digests")
    return weasyprint.HTML(string=document, url_fetcher=fetcher).write_pdf(
        attachments=[attachment])
