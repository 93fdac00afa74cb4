"""The station's reference standards and specified inputs (config/instruments/references.toml).

Each is a Type B input of some method's GUM budget (JCGM 100 4.3): its standard uncertainty, how it was obtained
(the distribution, whose first word says its shape) and the traceability statement the certificate carries
(ISO/IEC 17025 6.5, 7.8.4.1). Every method reads the file through `default_references` (once a process) unless
given other references.
"""

from __future__ import annotations

import functools
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

from procedures.common.certificate import with_unit
from procedures.common.uncertainty import Input, Shape, UncertaintyError, check_uncertainty
from station.defaults import config_file
from station.tomlfile import read_toml

REFERENCES_FILE = config_file("instruments", "references.toml")  # shipped defaults (station.defaults)


@dataclass(frozen=True)
class Reference:
    """One specified input: standard uncertainty, unit, how it was obtained and its traceability."""

    key: str
    quantity: str
    standard_uncertainty: float
    unit: str
    distribution: str
    traceability: str

    @property
    def shape(self) -> Shape:
        """The distribution's shape as the file states it: "rectangular ..." or anything else (normal)."""
        return "rectangular" if self.distribution.startswith("rectangular") else "normal"


def load_references(path: str | Path = REFERENCES_FILE) -> dict[str, Reference]:
    """The station's reference standards (config/instruments/references.toml)."""
    doc = read_toml(path, "references file", UncertaintyError).get("references", {})
    out = {}
    for key, r in doc.items():
        try:
            u = float(r["standard_uncertainty"])
        except (KeyError, TypeError, ValueError):
            raise UncertaintyError(
                f"references file {path}: [references.{key}] standard_uncertainty = "
                f"{r.get('standard_uncertainty')!r}: expected a number >= 0"
            ) from None
        check_uncertainty(key, 0.0, u)
        out[key] = Reference(key, str(r.get("quantity", key)), u, str(r.get("unit", "")),
                             str(r.get("distribution", "")), str(r.get("traceability", "not stated")))  # fmt: skip
    return out


@functools.cache
def default_references() -> Mapping[str, Reference]:
    """The shipped references file, read once (budgets run at every temperature, calibration, Monte Carlo draw)."""
    return load_references()


def reference_input(key: str, label: str, value: float, ref: Reference, *, u: float | None = None,
                    unit: str | None = None, note: str = "") -> Input:  # fmt: skip
    """A Type B input whose u (unless given in another unit), shape and distribution are the reference's."""
    return Input(key, label, value, ref.standard_uncertainty if u is None else u, ref.unit if unit is None else unit,
                 note or ref.distribution, shape=ref.shape)  # fmt: skip


def traceability(keys: Iterable[str], references: Mapping[str, Reference] | None = None) -> list[dict[str, str]]:
    """The certificate's traceability statement of each reference a method uses (ISO/IEC 17025 7.8.4.1)."""
    refs = references if references is not None else default_references()
    missing = [k for k in keys if k not in refs]
    if missing:
        raise UncertaintyError(f"references file: no [references.{missing[0]}] (the method's budget uses it)")
    return [{"quantity": refs[k].quantity, "standard_uncertainty": with_unit(f"{refs[k].standard_uncertainty:.3g}",
             refs[k].unit), "traceability": refs[k].traceability} for k in keys]  # fmt: skip
