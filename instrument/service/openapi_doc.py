"""The service's OpenAPI document, made to say what the server enforces.

FastAPI writes most of it from the routes. What it cannot know is added here: the request models
the routes parse themselves (for speed), the multipart body, the scene's sections and keys, and
the facts of the tables this process loaded: which sphere sizes, table ids and plate materials a
request may name. A client or a schema fuzzer that keeps to the document is then not refused for
a value the document allowed (cross-field rules, such as a scene's cost, remain for the route).
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from fastapi import FastAPI
from fastapi.openapi.utils import get_openapi
from pydantic import BaseModel

from solitonde.instrument.inference.table_set import TableSet
from solitonde.instrument.tables.family import differences
from solitonde.model.materials import MATERIALS, PROPERTY_RANGES, properties_from
from solitonde.model.scene import Scene

MATERIAL_OBJECT = {
    "type": "object", "additionalProperties": False,
    "required": ["youngs_modulus", "poisson_ratio", "density"],
    "properties": {"name": {"description": "a label (text, first 80 characters kept)"},
                   "youngs_modulus": {"type": "number", "description": "Pa",
                                      "minimum": PROPERTY_RANGES["youngs_modulus"][0],
                                      "maximum": PROPERTY_RANGES["youngs_modulus"][1]},
                   "poisson_ratio": {"type": "number", "exclusiveMinimum": -1,
                                     "exclusiveMaximum": 0.5},
                   "density": {"type": "number", "description": "kg/m^3",
                               "minimum": PROPERTY_RANGES["density"][0],
                               "maximum": PROPERTY_RANGES["density"][1]}},
    "description": "a material by its properties (SI)"}
"""A material by its properties, as :func:`~solitonde.model.materials.properties_from` takes it."""


def install(app: FastAPI, models: Iterable[type[BaseModel]]) -> None:
    """Give ``app`` an ``openapi()`` that adds ``models`` and, once the service has started,
    the loaded tables' sphere sizes, ids and plate materials."""
    from solitonde.instrument.service.authentication import SECURITY_SCHEMES
    from solitonde.instrument.service.measurement_forms import upload_schema

    models = tuple(models)

    def openapi() -> dict[str, Any]:
        if app.openapi_schema:
            return app.openapi_schema
        schema = get_openapi(title=app.title, version=app.version, description=app.description,
                             routes=app.routes, tags=app.openapi_tags)
        components = schema.setdefault("components", {}).setdefault("schemas", {})
        for model in models:
            js = model.model_json_schema(ref_template="#/components/schemas/{model}")
            components.update(js.pop("$defs", {}))
            components[model.__name__] = js
        components["MeasurementUpload"] = upload_schema()
        _scene(components)
        _links_from_plates(schema.get("paths", {}))
        schema["components"]["securitySchemes"] = SECURITY_SCHEMES
        for path, operations in schema.get("paths", {}).items():
            if path.startswith("/v1/"):
                for op in operations.values():
                    op["security"] = [{"APIKeyHeader": []}, {"HTTPBearer": []}, {}]
        service = getattr(app.state, "service", None)
        if service is not None:  # the tables are known once the lifespan has loaded them
            narrow_to_tables(components, service.tables)
            app.openapi_schema = schema
        return schema

    app.openapi = openapi  # type: ignore[method-assign]


def _scene(components: dict[str, Any]) -> None:
    """``SimulateIn.scene``: the scene's sections and their keys, unknown keys refused."""
    scene = Scene.model_json_schema(ref_template="#/components/schemas/{model}")
    defs = scene.pop("$defs", {})
    names = {"enum": sorted(MATERIALS), "type": "string", "description": "a library material"}
    for section in defs.values():
        material = section.get("properties", {}).get("material")
        if material is not None:
            material["anyOf"] = [names, MATERIAL_OBJECT]
    components.update(defs)
    components["Scene"] = scene
    simulate = components.get("SimulateIn", {}).get("properties", {})
    if "scene" in simulate:
        simulate["scene"] = {"$ref": "#/components/schemas/Scene",
                             "description": simulate["scene"].get("description", "")}


def _links_from_plates(paths: dict[str, Any]) -> None:
    """OpenAPI links from ``GET /v1/plates`` to a plate's map, for a stateful client."""
    listing = paths.get("/v1/plates", {}).get("get")
    if listing is None:
        return
    ok = listing.setdefault("responses", {}).setdefault("200", {"description": "the plates"})
    ok["links"] = {name: {"operationId": op,
                          "parameters": {"plate_id": "$response.body#/items/0/plate_id"}}
                   for name, op in (("PlateMap", "plate_map"), ("PlateMapPng", "plate_map_png"))}


def narrow_to_tables(components: dict[str, Any], tables: TableSet) -> None:
    """Sphere sizes, table ids and plate materials limited to what the loaded tables serve."""
    if not tables.loaded:
        return
    ids = list(tables.by_id)
    diameters = sorted({float(d) for est in tables.by_id.values()
                        for d in est.model.axes["diameter_m"]})
    materials = [name for name in sorted(MATERIALS) if any(
        est.model.family is None
        or not differences({"plate_material": properties_from(name)}, est.model.family)
        for est in tables.by_id.values())]
    for model in ("InvertIn", "ShotMetadata", "MeasurementUpload"):
        props = components.get(model, {}).get("properties", {})
        if "table" in props:
            props["table"] = _nullable({"type": "string", "enum": ids}, props["table"])
        if "plate_material" in props:
            by_properties = [a for a in props["plate_material"].get("anyOf", [])
                             if "$ref" in a or a.get("type") == "object"]
            props["plate_material"] = _nullable({"type": "string", "enum": materials},
                                                props["plate_material"])
            props["plate_material"]["anyOf"][1:1] = by_properties
    props = components.get("InversionInput", {}).get("properties", {})
    if "diameter_m" in props:  # a table serves its sizes within 1 % (TableSet's rule)
        props["diameter_m"] = {
            "anyOf": [{"type": "number", "minimum": d - _INSIDE * d, "maximum": d + _INSIDE * d}
                      for d in diameters],
            "description": "sphere diameter D, m: a size of the loaded tables (within 1 %): "
                           + ", ".join(f"{d:g}" for d in diameters)}


_INSIDE = 0.01 * (1 - 1e-9)
"""The 1 % tolerance, a hair inside so that rounding at the very edge is not a refusal."""


def _nullable(schema: dict[str, Any], old: dict[str, Any]) -> dict[str, Any]:
    out = {"anyOf": [schema, {"type": "null"}]}
    for key in ("default", "description", "title"):
        if key in old:
            out[key] = old[key]
    return out
