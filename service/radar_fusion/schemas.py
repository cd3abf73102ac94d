"""JSON Schema files of the wire contract, generated from the pydantic models (wire.py).

``schemas/`` in the repository holds the published, language-neutral contract; a test
regenerates them and fails when they drift from the models.
"""

from __future__ import annotations

import json
from pathlib import Path

from .wire import MESSAGE_MODELS


def schema_documents() -> dict[str, str]:
    """File name → JSON text, for every message of the contract."""
    docs = {}
    for name, model in MESSAGE_MODELS.items():
        schema = model.model_json_schema(mode="validation")
        schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
        schema["$id"] = f"radar-fusion/v1/{name}.schema.json"
        docs[f"{name}.schema.json"] = json.dumps(schema, indent=2, sort_keys=True, ensure_ascii=False) + "\n"
    return docs


def write_schemas(out_dir: str | Path) -> list[Path]:
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, text in schema_documents().items():
        path = out / name
        path.write_text(text, encoding="utf-8")
        paths.append(path)
    return paths
