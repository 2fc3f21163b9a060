"""Reading the library's data files (policies, tasks, pipelines, demonstrations, run configurations).

Every failure is a ``ValueError`` that names the file and, where there is one, the field: a damaged or hand-edited
file never surfaces as a bare ``JSONDecodeError``, ``BadZipFile`` or ``KeyError``, and never loads silently wrong.
"""

from __future__ import annotations

import json
import tomllib
import zipfile
from pathlib import Path

import numpy as np

__all__ = ["read_json", "read_toml", "read_npz", "read_metadata", "field"]


def read_json(path) -> dict:
    path = Path(path)
    try:
        value = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise ValueError(f"{path}: not valid JSON ({error})") from None
    if not isinstance(value, dict):
        raise ValueError(f"{path}: expected a JSON object at the top, got {type(value).__name__}")
    return value


def read_toml(path) -> dict:
    path = Path(path)
    try:
        return tomllib.loads(path.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as error:
        raise ValueError(f"{path}: not valid TOML ({error})") from None


def extended_chain(path) -> list[Path]:
    """The files a configuration is made of, the one it extends first: ``[run] extends = "<file>.toml"`` (a path
    beside it) followed to a file that extends none. A missing file, a chain that comes back to a file of its own
    and an ``extends`` that is not a file name are errors naming the file."""
    chain = [Path(path)]
    while True:
        path = chain[-1]
        run = read_toml(path).get("run")
        if not isinstance(run, dict) or "extends" not in run:
            return chain[::-1]
        base = run["extends"]
        if not isinstance(base, str) or not base.endswith(".toml"):
            raise ValueError(f"{path}: [run] extends: a configuration file's name (e.g. \"suction_debris_mappo.toml\"), "
                             f"got {base!r}")
        base_path = path.parent / base
        if base_path.resolve() in [link.resolve() for link in chain]:
            names = " -> ".join(link.name for link in chain)
            raise ValueError(f"{path}: [run] extends = {base!r} comes back to a file of its own chain ({names} -> {base})")
        if not base_path.is_file():
            raise ValueError(f"{path}: [run] extends = {base!r}: no such file {base_path}")
        chain.append(base_path)


def read_extended_toml(path) -> dict:
    """A configuration's tables with its :func:`extended_chain` followed: the file it extends, table by table and key
    by key overridden by this one's (``extends`` itself left out)."""
    merged: dict = {}
    for link in extended_chain(path):
        for section, content in read_toml(link).items():
            if isinstance(content, dict) and isinstance(merged.get(section), dict):
                merged[section] = {**merged[section], **content}
            else:
                merged[section] = content
    if isinstance(merged.get("run"), dict):
        merged["run"] = {key: value for key, value in merged["run"].items() if key != "extends"}
    return merged


def read_npz(path) -> dict[str, np.ndarray]:
    """Every array of an ``.npz`` file (no pickles), read eagerly."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as archive:
            return {key: archive[key] for key in archive.files}
    except (zipfile.BadZipFile, OSError, ValueError, EOFError) as error:
        raise ValueError(f"{path}: not a readable .npz archive ({error})") from None


def field(table: dict, name: str, path, kind=None, where: str = ""):
    """``table[name]``, or a ValueError naming the file and the missing (or mistyped) field."""
    label = f"{where}.{name}" if where else name
    if name not in table:
        raise ValueError(f"{path}: missing field {label!r}")
    value = table[name]
    if kind is not None and not isinstance(value, kind):
        names = kind.__name__ if isinstance(kind, type) else " or ".join(k.__name__ for k in kind)
        raise ValueError(f"{path}: field {label!r} must be {names}, got {type(value).__name__}")
    return value


def read_metadata(arrays: dict, path, expected_format: str) -> dict:
    """Pop and parse the JSON ``metadata`` array of an ``.npz`` data file and check its ``format``."""
    if "metadata" not in arrays:
        raise ValueError(f"{path}: missing array 'metadata'")
    try:
        metadata = json.loads(str(arrays.pop("metadata")))
    except json.JSONDecodeError as error:
        raise ValueError(f"{path}: field 'metadata' is not valid JSON ({error})") from None
    if not isinstance(metadata, dict) or metadata.get("format") != expected_format:
        found = metadata.get("format") if isinstance(metadata, dict) else metadata
        raise ValueError(f"{path}: field 'metadata.format' is {found!r}, expected {expected_format!r}")
    return metadata
