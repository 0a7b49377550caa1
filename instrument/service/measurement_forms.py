"""What an upload and a raw shot may say beside their samples: the multipart form's fields and
the binary route's query, as request models with the JSON shot's own limits, and their OpenAPI
schemas."""

from __future__ import annotations

import copy
import json
from typing import Any

from pydantic import ConfigDict, Field, create_model
from pydantic.fields import FieldInfo

from solitonde.instrument.service.api_models import (
    ALLOW_DUPLICATE_HELP,
    SETUP_HELP,
    BinaryShotParams,
    MaterialName,
    SetupName,
    ShotBase,
    ShotMetadata,
    Strict,
)
from solitonde.instrument.service.problems import Problem
from solitonde.instrument.service.uploads import FORMATS


def material_text(text: str) -> Any:
    """A form's or query's ``plate_material``: a library name, or its properties as JSON (a
    mapping, as a JSON body states it); 422 naming the field for JSON that is not one."""
    if not text.lstrip().startswith("{"):
        return text
    try:
        value = json.loads(text)
    except json.JSONDecodeError as exc:
        raise Problem(422, f"plate_material: not a JSON object ({exc.msg}); give a library "
                      "name or {\"youngs_modulus\", \"poisson_ratio\", \"density\"}",
                      kind="invalid-input", field="plate_material") from None
    if not isinstance(value, dict):
        raise Problem(422, "plate_material: expected a JSON object", kind="invalid-input",
                      field="plate_material")
    return value


def _optional(model: type[Strict], name: str) -> tuple[Any, FieldInfo]:
    """``model``'s field ``name``, with its limits and description, as an optional field."""
    info = copy.copy(model.model_fields[name])
    info.default = None
    annotation: Any = info.annotation
    return annotation | None, info


_METADATA_FORM_KEYS = ("plate_id", "position", "sphere_diameter", "x_m", "y_m", "table")


class _FormFields(Strict):
    # Form values arrive as text: numbers are parsed from it (still no NaN, no unknown fields).
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, strict=False)


UploadFields: Any = create_model(  # type: ignore[call-overload]  # fields from dicts
    "UploadFields",
    __base__=_FormFields,
    __doc__="Form fields that come with an uploaded file (all optional): the JSON shot's "
            "metadata and sampling, with the same limits, and the reader's options.",
    format=(str | None, Field(None, description=f"one of {', '.join(FORMATS)}; default: from "
                              "the file name's suffix")),
    **{k: _optional(ShotMetadata, k) for k in _METADATA_FORM_KEYS},
    plate_material=(MaterialName | None, Field(None, description="the plate's material: a "
                                               "library name, or its properties as JSON; the "
                                               "table of that family is used")),
    units=(str | None, Field(None, description="N or V, for files that do not say")),
    calibration=_optional(ShotBase, "calibration"),
    sample_rate=(float | None, Field(None, gt=0, le=1e10,
                                     description="Hz, for files without a time column")),
    **{k: _optional(ShotBase, k) for k in ("dt", "t0")},
    group=(str | None, Field(None, max_length=200, description="TDMS group: only its channels")),
    channel=(str | None, Field(None, max_length=200, description="the channel to analyse: a "
                               "column name, or a TDMS channel as group/channel or channel; "
                               "default: the file's channels that are sensor traces (a trigger "
                               "step or a flat line is skipped, and listed)")),
    dataset=(str | None, Field(None, max_length=200, description="HDF5 dataset")),
    allow_duplicate=(bool, Field(False, description=ALLOW_DUPLICATE_HELP)),
    setup=(SetupName | None, Field(None, description=SETUP_HELP)),
)
"""Form fields that come with an uploaded file; the metadata's and the sampling's limits are
:class:`ShotMetadata`'s and :class:`ShotBase`'s own (one declaration)."""




def binary_parameters() -> list[dict[str, Any]]:
    """OpenAPI query parameters of ``POST /v1/measurements/raw`` (``dtype`` and ``dt`` required)."""
    schema = BinaryShotParams.model_json_schema()
    required = set(schema.get("required", []))
    return [{"name": name, "in": "query", "required": name in required,
             "description": prop.get("description", name),
             "schema": {k: v for k, v in prop.items() if k not in ("title", "description")}}
            for name, prop in schema["properties"].items()]


def upload_schema() -> dict[str, Any]:
    """OpenAPI schema of the multipart body: a file plus :class:`UploadFields`."""
    schema = UploadFields.model_json_schema(ref_template="#/components/schemas/{model}")
    schema["title"] = "MeasurementUpload"
    schema["properties"] = {"file": {"type": "string", "format": "binary",
                                     "description": "CSV, NPY, NPZ, HDF5 or TDMS"},
                            **schema["properties"]}
    schema["required"] = ["file"]
    return schema
