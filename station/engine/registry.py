"""The procedure library's registry and the TOML procedure files operators start from.

A procedure file names a registered procedure and its parameters:

    procedure = "integral_precession"
    [params]
    positions_deg = [0, 36, 72]
    freqs_hz = [8, 9, 10]
"""

from __future__ import annotations

import importlib
import pkgutil
from collections.abc import Callable, Generator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from station.engine.design_checks import MethodCheck
from station.engine.params import Param, ParameterError, params_model, validate_params
from station.errors import InputError
from station.procedure_names import current_name
from station.session import Session
from station.tomlfile import read_toml


class ProcedureError(InputError):
    """An unknown procedure or a malformed procedure file."""


@dataclass(frozen=True)
class Analysis:
    """What a procedure's analysis makes of a finished session."""

    results: dict[str, dict]  # method -> JSON result, stored with the session
    report_html: str  # a self-contained HTML report
    summary: str  # a few lines for the console
    files: dict[str, bytes] = field(default_factory=dict)  # written beside the report (a certificate, ...)


Analyser = Callable[[Session], Analysis]


@dataclass(frozen=True)
class ProcedureSpec:
    name: str
    title: str
    params: tuple[Param, ...]
    func: Callable[[dict[str, Any]], Generator]
    analyse: Analyser | None = None  # run on the finished session, if any
    check_design: MethodCheck | None = None  # the method's own checks of a design (a singular one, ...)

    def validate(self, given: dict[str, Any]) -> dict[str, Any]:
        return validate_params(self.name, self.params, given)

    def describe(self) -> dict:
        """Name, title and declared parameters (and their JSON schema, from the same declaration), for forms."""
        return {"name": self.name, "title": self.title, "params": [p.describe() for p in self.params],
                "schema": params_model(self.name, self.params).model_json_schema()}  # fmt: skip


_REGISTRY: dict[str, ProcedureSpec] = {}


def procedure(
    name: str,
    title: str,
    params: Sequence[Param],
    analyse: Analyser | None = None,
    check_design: MethodCheck | None = None,
):
    """Register a generator function as a library procedure (check_design: the method's checks of a design)."""

    def register(func):
        _REGISTRY[name] = ProcedureSpec(name, title, tuple(params), func, analyse, check_design)
        return func

    return register


def load_library() -> dict[str, ProcedureSpec]:
    """Import the procedure modules (`procedure*.py`) of every method package so that their procedures register."""
    import procedures

    for pkg in pkgutil.iter_modules(procedures.__path__):
        if not pkg.ispkg:
            continue
        package = importlib.import_module(f"procedures.{pkg.name}")
        for mod in pkgutil.iter_modules(package.__path__):
            if mod.name.startswith("procedure"):
                importlib.import_module(f"procedures.{pkg.name}.{mod.name}")
    return dict(_REGISTRY)


def get_procedure(name: str) -> ProcedureSpec:
    """The registered procedure of that name, or of the name it had in an earlier version (station.procedure_names)."""
    library = load_library()
    spec = library.get(current_name(name))
    if spec is None:
        raise ProcedureError(f"unknown procedure {name!r}; the library has: {', '.join(sorted(library))}")
    return spec


def load_procedure_file(path: str | Path) -> tuple[ProcedureSpec, dict[str, Any]]:
    """Read and validate a TOML procedure file: (procedure, typed parameters)."""
    path = Path(path)
    doc = read_toml(path, "procedure file", ProcedureError)
    unknown = sorted(set(doc) - {"procedure", "params", "title", "instrument_serial"})
    if unknown:
        raise ProcedureError(
            f"procedure file {path}: unknown key(s) {unknown}; allowed: procedure, params, title, instrument_serial"
        )
    name = doc.get("procedure")
    if not isinstance(name, str):
        raise ProcedureError(f"procedure file {path}: 'procedure' = {name!r}: expected the name of a procedure")
    params = doc.get("params", {})
    if not isinstance(params, dict):
        raise ProcedureError(f"procedure file {path}: [params] must be a table")
    spec = get_procedure(name)
    try:
        return spec, spec.validate(params)
    except ParameterError as exc:
        raise ProcedureError(f"procedure file {path}: {exc}") from None


def procedure_file_serial(path: str | Path) -> str:
    """The instrument serial number a procedure file names (`instrument_serial`), '' when it names none."""
    path = Path(path)
    serial = read_toml(path, "procedure file", ProcedureError).get("instrument_serial", "")
    if not isinstance(serial, str):
        raise ProcedureError(f"procedure file {path}: 'instrument_serial' = {serial!r}: expected text (PIGA-0042)")
    return serial.strip()
