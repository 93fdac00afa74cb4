"""The certificate of a calibration session: what every method's certificate shares (ISO/IEC 17025 7.8).

A method hands `session_certificate` its session, the budgets it certifies (each a `Certified`: the coefficients
and their budget table), its `MethodCard` (title, method, procedure, the references its budgets use, its
instrument file), its residual figures and its own remarks; this fills in the rest the same way for every
method: identification (lab, station, instrument, serial, method, procedure and software version, operator),
dates, environmental conditions from the session's sensors (else "not measured"), results with U and k and their
conformity under the decision rule, the remarks on k, few degrees of freedom and undecided conformity,
traceability, and SIMULATED for a simulated station. `certificate_files` renders it as the HTML and PDF files
the analysis writes beside its report.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from procedures.common.certificate import (
    DEFAULT_INSTRUMENT_FILE,
    NOT_MEASURED,
    NOT_RECORDED,
    Certificate,
    CertificateError,
    InstrumentSpec,
    TableText,
    budget_rows,
    load_instrument_spec,
    load_laboratory,
    not_applicable,
    render_html,
    render_pdf,
    result_rows,
)
from procedures.common.papers import papers_cited
from procedures.common.references import traceability
from procedures.common.uncertainty import COVERAGE_RULE, MIN_RELIABLE_DOF, Budget
from station.interchange import content_hash
from station.session import Session

SIMULATED_CUSTOMER = "SIMULATED CUSTOMER (a simulated station calibrates no one's instrument)"
LISTED_POSITIONS = 24  # the conditions list the head's positions one by one up to this many
BUDGET_COLUMNS = 6  # coefficients per budget table: wider tables do not fit an A4 page


@dataclass(frozen=True)
class Certified:
    """One budget on the certificate: its coefficients as results (named prefix + name + suffix) and, unless
    `table` is None, its budget table under that title; limit_names maps a coefficient to its limit in the
    instrument file."""

    budget: Budget
    prefix: str = ""
    suffix: str = ""
    table: str | None = "Uncertainty budget"
    limit_names: Mapping[str, str] = field(default_factory=dict)


@dataclass(frozen=True)
class MethodCard:
    """What a method's certificate says of the method: its title, the method in words, its procedure (the
    session's own name wins) and procedure title, the keys of config/instruments/references.toml its budgets use
    (their traceability) and the instrument file of its limits."""

    title: str
    method: str
    procedure: str
    procedure_title: str
    references: tuple[str, ...]
    instrument_file: Path = DEFAULT_INSTRUMENT_FILE


def or_not_recorded(v: object) -> str:
    return NOT_RECORDED if v in (None, "") else str(v)


def provenance_of(session: Session) -> dict:
    """The session's provenance (issue 14) if it has one, else an empty record."""
    prov = getattr(session, "provenance", None) or session.meta.get("provenance") or {}
    return dict(prov)


def session_uid(session: Session) -> str:
    """The session's uid as its results, report and certificate name it: the store's (an export keeps it, and so
    does its import), else, for a piga-session/1 directory never stored, "sha256-" and the first 16 hex digits of
    its content hash (station.interchange.content_hash, of what it measured): the same directory is always named
    the same, and two sessions never share a certificate number."""
    uid = session.meta.get("store_uid")
    return str(uid) if uid else f"sha256-{content_hash(session)[:16]}"


def result_provenance(session: Session) -> dict:
    """Session identity for the result JSON: uid, instrument serial, station, operator, dates, software, simulated."""
    prov = provenance_of(session)
    keys = ("station_id", "operator", "host", "created_utc", "software_version", "simulated", "seed")
    out = {"session_uid": session_uid(session),
           "instrument_serial": prov.get("instrument_serial") or session.meta.get("instrument_serial") or NOT_RECORDED,
           "procedure": or_not_recorded(session.meta.get("procedure"))}  # fmt: skip
    out |= {k: NOT_RECORDED if prov.get(k) in (None, "") else prov[k] for k in keys}
    out["analysed_utc"] = datetime.now(UTC).isoformat(timespec="seconds")
    return out


def is_simulated(session: Session) -> bool:
    """The provenance says so; without one, the instrument's serial: a simulated one's ("SIM-..."), or none at all
    (a real station does not start without a serial: only the twin's sessions have none)."""
    prov = provenance_of(session)
    if prov.get("simulated") is not None:
        return bool(prov["simulated"])
    serial = str(prov.get("instrument_serial") or session.meta.get("instrument_serial") or "")
    return not serial or "SIM" in serial


def customer(session: Session, simulated: bool) -> str:
    """The customer the session's provenance names (`--customer`); a real session without one is refused."""
    name = provenance_of(session).get("customer")
    if name:
        return str(name)
    if simulated:
        return SIMULATED_CUSTOMER
    raise CertificateError(f"session {session_uid(session)}: provenance.customer is not set: a real "
                           "station's certificate names the customer (station run --customer NAME)")  # fmt: skip


def calibration_conditions(session: Session) -> list[tuple[str, str]]:
    """The conditions the session's windows were measured under: the head's positions, the table's frequencies and
    amplitude A0 (static windows: the table at rest), the window lengths Tm; the site's latitude and g."""
    st, points = session.station, session.points
    out = []
    if points:
        positions = sorted({round(p.position_deg, 4) for p in points})
        listed = ", ".join(f"{x:g}" for x in positions) if len(positions) <= LISTED_POSITIONS else (
            f"from {positions[0]:g} to {positions[-1]:g}")  # fmt: skip
        out.append(("indexing head positions", f"{len(positions)}: {listed} deg"))
        freqs = sorted({round(p.freq_hz, 4) for p in points if p.freq_hz > 0})
        static = sum(p.freq_hz <= 0 for p in points)
        table = [f"{', '.join(f'{f:g}' for f in freqs)} Hz at amplitude A0 = {st.A0_m * 1e3:g} mm"] if freqs else []
        out.append(("vibration table", "; ".join(table + [f"{static} static windows (table at rest)"] * bool(static))))
        tm = [p.Tm_s for p in points]
        out.append(("measurement windows Tm", f"{len(points)} windows, {min(tm):.1f} to {max(tm):.1f} s"))
    out.append(("site", f"latitude {st.latitude_deg:g} deg, local gravity g = {st.g_mps2:.8g} m/s^2"))
    return out


def environment_conditions(session: Session) -> list[tuple[str, str]]:
    """Temperature from the points' temperature_c column or the measurements' arrays, else not measured."""
    temps = [float(p.extra["temperature_c"]) for p in session.points if p.extra.get("temperature_c") not in (None, "")]
    for m in session.measurements:
        if "temperature_c" in m.arrays:
            temps += [float(x) for x in np.ravel(m.arrays["temperature_c"])]
    out = []
    if temps:
        out.append(("temperature", f"{min(temps):.2f} to {max(temps):.2f} °C ({len(temps)} readings of the station's "
                                   "sensors)"))  # fmt: skip
    else:
        out.append(("temperature", f"{NOT_MEASURED} (the station has no temperature sensor on this session)"))
    out.append(("humidity, pressure, magnetic field", f"{NOT_MEASURED} (no sensor on the station)"))
    return out


def measured_span_s(session: Session) -> float | None:
    """Station time from the first to the last measurement: the points' windows, else the measurements' t_s."""
    if session.points:
        return max(p.start_s + p.Tm_s for p in session.points) - min(p.start_s for p in session.points)
    t = [float(m.values["t_s"]) for m in session.measurements if isinstance(m.values.get("t_s"), int | float)]
    return max(t) - min(t) if len(t) > 1 else None


def measurement_duration(session: Session) -> str:
    """The session's duration as the console and the certificate print it: "6.63 h of station time (40 points)",
    from the first window's opening to the last one's close (measured_span_s)."""
    span = measured_span_s(session)
    if span is None:
        return "no measurement recorded"
    n = len(session.points) or len(session.measurements)
    return f"{span / 3600:.2f} h of station time ({n} {'points' if session.points else 'measurements'})"


def _dates(session: Session) -> list[tuple[str, str]]:
    return [
        ("date of calibration (session start)", or_not_recorded(provenance_of(session).get("created_utc"))),
        ("duration of the measurements", measurement_duration(session)),
        ("date of issue", datetime.now(UTC).isoformat(timespec="seconds")),
    ]


def _budget_tables(parts: Sequence[Certified]) -> list[TableText]:
    out: list[TableText] = []
    for part in parts:
        if part.table is None:
            continue
        names = part.budget.names
        for i in range(0, len(names), BUDGET_COLUMNS):
            chunk = names[i : i + BUDGET_COLUMNS]
            more = f" ({chunk[0]} .. {chunk[-1]})" if len(names) > BUDGET_COLUMNS else ""
            out.append((part.table + more, *budget_rows(part.budget, names=chunk)))
    return out


def _remarks(parts: Sequence[Certified], rows: Sequence[Any], own: Iterable[str]) -> list[str]:
    out = [*own, "The expanded uncertainty U = k u_c has a coverage probability of about 95 %. " + COVERAGE_RULE + "."]
    few = [p.prefix + n + p.suffix for p in parts for n in p.budget.few_dof()]
    if few:
        out.append(f"Few degrees of freedom: {', '.join(few)} rest on fewer than {MIN_RELIABLE_DOF} effective "
                   "degrees of freedom; their U uses the larger t factor and a design with more points is "
                   "advised for a reliable uncertainty.")  # fmt: skip
    if any(r.conformity == "not decided" for r in rows):
        out.append("'not decided': the value lies within U of a limit, so conformity cannot be stated at 95 %.")
    out += [f"Not applicable: {s.source} (u = 0 on this session: {s.note or 'no uncertainty stated'}); left out of "
            "the budget table." for p in parts for s in not_applicable(p.budget)]  # fmt: skip
    return out


def session_certificate(
    session: Session,
    parts: Sequence[Certified],
    card: MethodCard,
    *,
    spec: InstrumentSpec | None = None,
    figures: Sequence[tuple[str, Callable[[], Any]]] = (),
    remarks: Iterable[str] = (),
    environment: Sequence[tuple[str, str]] | None = None,
    identification: Sequence[tuple[str, str]] = (),
    extra_tables: Sequence[TableText] = (),
    conditions: Sequence[tuple[str, str]] = (),
) -> Certificate:
    """The certificate of `session` for the budgets `parts` of the method `card` (its limits from `spec`, else from
    the card's instrument file); `identification`: rows beside the common ones; `conditions`: the method's own
    before those of the session's points and site."""
    spec = spec or load_instrument_spec(card.instrument_file)
    procedure = f"{session.meta.get('procedure') or card.procedure} {card.procedure_title}"
    prov = provenance_of(session)
    uid = session_uid(session)
    simulated = is_simulated(session)
    serial = prov.get("instrument_serial") or session.meta.get("instrument_serial")
    laboratory = load_laboratory(simulated)
    ident = [
        ("customer", customer(session, simulated)),
        ("place of calibration", laboratory["place_of_calibration"]),
        ("station", or_not_recorded(prov.get("station_id"))),
        ("instrument", spec.model),
        ("manufacturer", spec.manufacturer),
        ("serial number", or_not_recorded(serial)),
        ("specification (instrument file)", f"{spec.specification} ({Path(spec.path).name})"),
        ("calibration session", uid),
        ("method", card.method),
        ("procedure and version", f"{procedure}; software {or_not_recorded(prov.get('software_version'))}"),
        ("operator", or_not_recorded(prov.get("operator"))),
        ("host", or_not_recorded(prov.get("host"))),
        ("simulated", "yes: digital twin, seed " + or_not_recorded(prov.get("seed")) if simulated else "no"),
        *identification,
    ]
    rows = [r for p in parts for r in result_rows(p.budget.coefficients_json(), spec, prefix=p.prefix,
                                                   suffix=p.suffix, limit_names=p.limit_names)]  # fmt: skip
    cert = Certificate(
        certificate_id=f"CERT-{uid}",
        title=card.title,
        laboratory=laboratory,
        identification=ident,
        dates=_dates(session),
        environment=environment if environment is not None else environment_conditions(session),
        results=rows,
        decision_rule=f"{spec.decision_rule_name}: {spec.decision_rule}",
        traceability=traceability(card.references),
        budgets=_budget_tables(parts),
        figures=figures,
        remarks=_remarks(parts, rows, remarks),
        simulated=simulated,
        extra_tables=extra_tables,
        conditions=[*conditions, *calibration_conditions(session)],
    )
    named = [cert.title, cert.decision_rule, *cert.remarks, *(caption for caption, _ in figures)]
    tables = [cert.identification, cert.environment, cert.traceability, cert.budgets, cert.extra_tables]
    cert.papers = papers_cited(named + [repr(t) for t in tables])
    return cert


def certificate_files(cert: Certificate, uid: str) -> dict[str, bytes]:
    """certificate-<uid>.html and .pdf, as an analysis returns them (station.cli.analysis_job writes them beside the
    report)."""
    stem = f"certificate-{uid}"
    return {f"{stem}.html": render_html(cert).encode(), f"{stem}.pdf": render_pdf(cert)}


def issue_certificate(build: Callable[[], Certificate | None], uid: str) -> tuple[dict[str, bytes], str]:
    """The certificate's files, or none and the line that says why not: a session is analysed and reported even
    when its certificate cannot be issued (a real station without config/laboratory.toml's keys or a customer);
    `build` returning None (nothing to certify) gives no files and leaves the reason to the procedure."""
    try:
        cert = build()
    except CertificateError as exc:
        return {}, f"no certificate: {exc}"
    return ({} if cert is None else certificate_files(cert, uid)), ""
