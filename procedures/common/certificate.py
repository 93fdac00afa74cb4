"""Calibration certificate (ISO/IEC 17025:2017 clause 7.8.2 and 7.8.4) as HTML (Jinja2) and PDF (reportlab).

A `Certificate` holds the lab, station, instrument, method and procedure version, dates, environmental
conditions, results with U and k, traceability, conformity against the instrument file's limits with the
decision rule, the budget tables and the residual figures (procedures.common.session_certificate fills it from a
session and its budgets); this module renders it. Every page of a simulated station's certificate says
SIMULATED; pages are numbered "page i of n" (HTML: @page margin boxes; PDF: a two-pass canvas).
"""

from __future__ import annotations

import io
import math
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import jinja2
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
from reportlab.lib import colors
from reportlab.lib.pagesizes import A4
from reportlab.lib.styles import ParagraphStyle, getSampleStyleSheet
from reportlab.lib.units import mm
from reportlab.pdfgen import canvas as rl_canvas
from reportlab.platypus import Image, KeepTogether, Paragraph, SimpleDocTemplate, Spacer, Table, TableStyle

from procedures.common.uncertainty import Budget, Source
from station.defaults import config_file
from station.htmlkit import esc, svg
from station.tomlfile import read_toml

INSTRUMENTS_DIR = config_file("instruments")  # shipped defaults (station.defaults)
DEFAULT_INSTRUMENT_FILE = INSTRUMENTS_DIR / "piga-sim.toml"
LABORATORY_FILE = config_file("laboratory.toml")
LABORATORY_KEYS = ("name", "address", "place_of_calibration")  # a real station's certificate needs each
SIMULATED_LABORATORY = {
    "name": "SIMULATED LABORATORY",
    "address": "no address (simulated station)",
    "place_of_calibration": "the station's digital twin (no instrument was calibrated)",
    "accreditation": "",
}
NOT_MEASURED = "not measured"
NOT_RECORDED = "not recorded"
CONDITIONS = "3. Calibration and environmental conditions"
PAPERS_NOTE = "equation, table and figure numbers are the paper's"
UNBROKEN_CELL = 26  # characters: a PDF table cell this short is one line (no number broken across lines)
Conformity = Literal["conforms", "does not conform", "not decided", "no limit"]


class CertificateError(ValueError):
    """An instrument file or certificate input that cannot be used (names the field and what is allowed)."""


@dataclass(frozen=True)
class Limit:
    name: str
    min: float
    max: float
    unit: str


@dataclass(frozen=True)
class InstrumentSpec:
    """An instrument file (config/instruments/*.toml): identity, limits per coefficient and the decision rule."""

    path: str
    model: str
    manufacturer: str
    specification: str
    limits: Mapping[str, Limit]
    decision_rule_name: str
    decision_rule: str


def load_instrument_spec(path: str | Path = DEFAULT_INSTRUMENT_FILE) -> InstrumentSpec:
    """Read and check an instrument file: every limit needs numbers min < max."""
    doc = read_toml(path, "instrument file", CertificateError)
    inst = doc.get("instrument", {})
    rule = doc.get("decision_rule", {})
    if not rule.get("text"):
        raise CertificateError(f"instrument file {path}: [decision_rule] text is missing: the rule must be stated")
    limits = {}
    for name, lim in doc.get("limits", {}).items():
        lo, hi = lim.get("min"), lim.get("max")
        ok = all(isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x) for x in (lo, hi))
        if not ok or not lo < hi:
            raise CertificateError(
                f"instrument file {path}: [limits.{name}] min = {lo!r}, max = {hi!r}: "
                "expected finite numbers with min < max"
            )
        limits[name] = Limit(name, float(lo), float(hi), str(lim.get("unit", "")))
    return InstrumentSpec(str(path), str(inst.get("model", NOT_RECORDED)), str(inst.get("manufacturer", NOT_RECORDED)),
                          str(inst.get("specification", NOT_RECORDED)), limits, str(rule.get("name", "")),
                          str(rule["text"]))  # fmt: skip


CONFORMITY_TEXT: Mapping[Conformity, str] = {"not decided": "not decided (U straddles the limit)"}
DIMENSIONLESS = "(dimensionless)"


def conformity(value: float, expanded: float, limit: Limit | None) -> Conformity:
    """Guarded acceptance (ILAC-G8 4.2.2, guard band w = U): inside by U conforms, outside by U does not."""
    if limit is None:
        return "no limit"
    if limit.min + expanded <= value <= limit.max - expanded:
        return "conforms"
    if value < limit.min - expanded or value > limit.max + expanded:
        return "does not conform"
    return "not decided"


def two_significant(x: float) -> tuple[str, int]:
    """x to two significant digits in e-notation ("1.0e-06" for 9.96e-07) and the decimal place of its last digit."""
    text = f"{x:.1e}"
    return text, int(text.split("e")[1]) - 1


def gum_round(value: float, expanded: float) -> tuple[str, str]:
    """The value and its U as the certificate prints them (GUM 7.2.6): U to two significant digits, the value to
    the same decimal place, in the larger of the two exponents; a U that is not positive leaves the value at 7
    significant digits."""
    if not (math.isfinite(expanded) and expanded > 0) or not math.isfinite(value):
        return f"{value:.6e}", f"{expanded:.2g}"
    u_text, place = two_significant(expanded)
    rounded = round(value, -place)
    exponent = max(int(f"{rounded:e}".split("e")[1]) if rounded else place + 1, place + 1)
    digits = exponent - place
    return f"{rounded / 10**exponent:.{digits}f}e{exponent:+03d}", u_text


def unit_text(unit: str) -> str:
    """A unit as the certificate prints it: a dimensionless quantity ("" or "1") says so, never "1"."""
    return DIMENSIONLESS if unit.strip() in ("", "1") else unit


def with_unit(number: str, unit: str) -> str:
    """A number and its unit kept on one line (a no-break space); a dimensionless number stands alone."""
    return number if unit_text(unit) == DIMENSIONLESS else f"{number}\u00a0{unit}"


def load_laboratory(simulated: bool, path: str | Path = LABORATORY_FILE) -> dict[str, str]:
    """The issuing laboratory and the place of calibration ([laboratory] of config/laboratory.toml): name, address,
    place_of_calibration, accreditation (optional). A simulated station's missing key says SIMULATED LABORATORY;
    a real station's is refused (CertificateError naming the file and key): never a placeholder on the certificate."""
    lab = read_toml(path, "laboratory file", CertificateError).get("laboratory", {})
    out = {}
    for key in (*LABORATORY_KEYS, "accreditation"):
        value = str(lab.get(key, "")).strip()
        if not value and simulated:
            value = SIMULATED_LABORATORY[key]
        elif not value and key != "accreditation":
            raise CertificateError(f"laboratory file {path}: [laboratory] {key} is not set: a real station's "
                                   "certificate names the laboratory that issues it")  # fmt: skip
        out[key] = value
    return out


@dataclass(frozen=True)
class ResultRow:
    name: str
    value: float
    unit: str
    standard_uncertainty: float
    effective_dof: float
    coverage_factor: float
    coverage_probability: float
    expanded_uncertainty: float
    conformity: Conformity
    limit: str

    def cells(self) -> tuple[str, ...]:
        """coefficient, value, unit, u, nu_eff, k, U, limits, conformity as printed (GUM 7.2.6 rounding)."""
        value, big_u = gum_round(self.value, self.expanded_uncertainty)
        return (self.name, value, unit_text(self.unit), two_significant(self.standard_uncertainty)[0],
                fmt_dof(self.effective_dof), f"{self.coverage_factor:.2f}", big_u, self.limit,
                CONFORMITY_TEXT.get(self.conformity, self.conformity))  # fmt: skip


RESULT_HEADER = ("coefficient", "value", "unit", "u", "ν_eff", "k", "U", "limits", "conformity")
TableText = tuple[str, Sequence[str], Sequence[Sequence[str]]]  # (title, header, rows)


@dataclass
class Certificate:
    """Everything clause 7.8 asks of a calibration certificate, already formatted as text where it is text."""

    certificate_id: str
    title: str
    laboratory: Mapping[str, str]
    identification: Sequence[tuple[str, str]]  # station, instrument, serial, method, procedure, software ...
    dates: Sequence[tuple[str, str]]
    environment: Sequence[tuple[str, str]]  # (quantity, value) or [("conditions", NOT_MEASURED)]
    results: Sequence[ResultRow]
    decision_rule: str
    traceability: Sequence[Mapping[str, str]]
    budgets: Sequence[TableText]  # one table per budget (or per group of its coefficients)
    figures: Sequence[tuple[str, Callable[[], Any]]] = ()  # (caption, a maker of a matplotlib figure)
    remarks: Sequence[str] = ()
    simulated: bool = False
    conditions: Sequence[tuple[str, str]] = ()  # (condition, value): positions, frequencies, amplitude, windows
    papers: Sequence[str] = ()  # "seed NNN: full citation" of every seed paper the certificate names
    signatures: Sequence[str] = ("Calibrated by", "Reviewed and approved by")
    extra_tables: Sequence[TableText] = field(default_factory=tuple)


def result_rows(coefficients: Mapping[str, Mapping[str, Any]], spec: InstrumentSpec | None, *, prefix: str = "",
                suffix: str = "", limit_names: Mapping[str, str] | None = None) -> list[ResultRow]:  # fmt: skip
    """Rows from a budget's coefficients_json(), named prefix + name + suffix, with the conformity of each against
    the limit of `spec` named limit_names.get(name, name)."""
    rows = []
    for name, c in coefficients.items():
        lim = spec.limits.get((limit_names or {}).get(name, name)) if spec else None
        nu = c.get("effective_dof")
        rows.append(ResultRow(prefix + name + suffix, c["value"], c.get("unit", ""), c["standard_uncertainty"],
                              math.inf if nu is None else float(nu), c["coverage_factor"], c["coverage_probability"],
                              c["expanded_uncertainty"], conformity(c["value"], c["expanded_uncertainty"], lim),
                              f"[{lim.min:.4g},\u00a0{lim.max:.4g}]" if lim else "none"))  # fmt: skip
    return rows


def fmt_dof(nu: float) -> str:
    return "∞" if math.isinf(nu) else f"{nu:.1f}" if nu < 1000 else f"{nu:.2g}"


def not_applicable(budget: Budget) -> list[Source]:
    """The Type B inputs with u = 0 (a term this session does not have): left out of the budget table, stated in
    the certificate's remarks with the reason their note gives."""
    return [s for s in budget.sources if s.type == "B" and s.standard_uncertainty == 0]


def budget_rows(budget: Budget, *, with_sensitivity: bool = False,
                names: Sequence[str] | None = None) -> tuple[list[str], list[list[str]]]:  # fmt: skip
    """Header and rows of the budget table: source, type, value, u(x), nu, then per coefficient (of `names`, default
    all) |c| u (and c); the combined u_c, nu_eff and U = k u_c at the foot."""
    cols = [budget.names.index(n) for n in (names or budget.names)]
    header = ["source", "type", "value x", "u(x)", "ν"]
    for j in cols:
        n = budget.names[j]
        if with_sensitivity:
            header.append(f"c = ∂{n}/∂x")
        header.append(f"u_i({n}) ({unit_text(budget.units.get(n, ''))})")
    rows = []
    for s in budget.sources:
        if s in not_applicable(budget):
            continue
        label = s.source + ("" if s.in_combined else " [listed, not added]")
        val = "—" if s.type == "A" else with_unit(f"{s.value:.4g}", s.unit)
        ux = "—" if s.type == "A" else with_unit(f"{s.standard_uncertainty:.2e}", s.unit)
        row = [label, s.type, val, ux, fmt_dof(s.dof)]
        for j in cols:
            if with_sensitivity:
                row.append("—" if s.type == "A" else f"{s.sensitivity[j]:.3e}")
            row.append(f"{s.contribution[j]:.2e}")
        rows.append(row)
    uc, nu, k = budget.standard_uncertainty(), budget.effective_dof(), budget.coverage_factors()
    totals = (
        ("combined standard uncertainty u_c", [two_significant(uc[j])[0] for j in cols]),
        ("effective dof ν_eff (Welch-Satterthwaite)", [fmt_dof(nu[j]) for j in cols]),
        ("expanded U = k u_c (k at 95 %)", [f"{two_significant(k[j] * uc[j])[0]} (k {k[j]:.2f})" for j in cols]),
    )
    for label, cells in totals:
        row = [label, "", "", "", ""]
        for c in cells:
            row += ["", c] if with_sensitivity else [c]
        rows.append(row)
    return header, rows


_ENV = jinja2.Environment(
    loader=jinja2.PackageLoader("procedures.common", "templates"),
    autoescape=jinja2.select_autoescape(["html", "j2"]),
    undefined=jinja2.StrictUndefined,
)


def render_html(cert: Certificate) -> str:
    """The certificate as one self-contained HTML page (figures inline as SVG), print-ready (A4, page numbers)."""
    figures = [(caption, svg(make())) for caption, make in cert.figures]
    return _ENV.get_template("certificate.html.j2").render(
        c=cert, figures=figures, result_header=RESULT_HEADER, conditions=CONDITIONS, papers_note=PAPERS_NOTE
    )


def _png(fig) -> tuple[bytes, float]:
    buf = io.BytesIO()
    w, h = fig.get_size_inches()
    fig.savefig(buf, format="png", dpi=200, bbox_inches="tight")
    plt.close(fig)
    return buf.getvalue(), h / w


class _NumberedCanvas(rl_canvas.Canvas):
    """Two passes: pages are kept until the total is known, then each gets 'page i of n' and the banner."""

    def __init__(self, *args, cert_id: str = "", simulated: bool = False, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self._pages: list[dict] = []
        self._cert_id, self._simulated = cert_id, simulated

    def showPage(self) -> None:  # reportlab's name
        self._pages.append(dict(self.__dict__))
        self._startPage()

    def save(self) -> None:
        n = len(self._pages)
        for state in self._pages:
            self.__dict__.update(state)
            self._decorate(n)
            super().showPage()
        super().save()

    def _decorate(self, n: int) -> None:
        w, h = A4
        self.setFont("Helvetica", 8)
        self.setFillColor(colors.black)
        self.drawString(15 * mm, 10 * mm, f"Certificate {self._cert_id}")
        self.drawRightString(w - 15 * mm, 10 * mm, f"page {self._pageNumber} of {n}")
        if self._simulated:
            self.setFont("Helvetica-Bold", 11)
            self.setFillColor(colors.red)
            self.drawCentredString(w / 2, h - 10 * mm, "SIMULATED STATION: NOT A CALIBRATION OF A REAL INSTRUMENT")
            self.saveState()
            self.setFont("Helvetica-Bold", 70)
            self.setFillColor(colors.Color(1, 0, 0, alpha=0.10))
            self.translate(w / 2, h / 2)
            self.rotate(45)
            self.drawCentredString(0, 0, "SIMULATED")
            self.restoreState()


_PDF_TEXT = str.maketrans(
    {
        "ν": "nu",
        "σ": "sigma",
        "μ": "mu",
        "∞": "inf",
        "θ": "theta",
        "ψ": "psi",
        "ω": "w",
        "≤": "<=",
        "≥": ">=",
        "√": "sqrt",
        "·": "*",
        "−": "-",
        "Δ": "Delta",
        "λ": "lambda",
        "β": "beta",
        "γ": "gamma",
        "δ": "delta",
        "ε": "eps",
        "τ": "tau",
        "φ": "phi",
        "∂": "d",
        "″": '"',
        "′": "'",
    }
)


# A number and the unit after it are one word to a line break (GUM 7.2.6's "no number broken across lines").
_NUMBER_UNIT = re.compile(r"(\d) (?=(?:um|µm|mm|m|Hz|ns|us|µs|ms|s|h|deg|arcsec|rad|g|V|uV|kg|ppm|%)(?![\w/^]))")


def pdf_chars(x: object) -> str:
    """Text in the PDF's standard fonts (WinAnsi): Greek letters and math signs spelled out, a number bound to its
    unit by a no-break space."""
    return _NUMBER_UNIT.sub("\\1\u00a0", str(x)).translate(_PDF_TEXT)


def pdf_text(x: object) -> str:
    """`pdf_chars` escaped for a reportlab paragraph."""
    return esc(pdf_chars(x))


def render_pdf(cert: Certificate) -> bytes:
    """The certificate as PDF (A4): the same content as the HTML, figures as 200 dpi PNG."""
    buf = io.BytesIO()
    styles = getSampleStyleSheet()
    small = ParagraphStyle("small", parent=styles["BodyText"], fontSize=8, leading=10)
    cell = ParagraphStyle("cell", parent=small, fontSize=7, leading=8.5)
    story: list[Any] = [Paragraph(pdf_text(cert.title), styles["Title"])]
    lab = cert.laboratory
    accreditation = f". {pdf_text(lab['accreditation'])}" if lab.get("accreditation") else ""
    story.append(Paragraph(f"<b>{pdf_text(lab['name'])}</b>, {pdf_text(lab['address'])}{accreditation}", small))
    story.append(Paragraph(f"Certificate number <b>{pdf_text(cert.certificate_id)}</b>", small))

    def tbl(header: Sequence[str] | None, rows: Sequence[Sequence[str]], widths=None) -> Table:
        data = ([[Paragraph(f"<b>{pdf_text(h)}</b>", cell) for h in header]] if header else []) + [
            [_pdf_cell(str(x), cell) for x in r] for r in rows
        ]
        t = Table(data, colWidths=widths, repeatRows=1 if header else 0, hAlign="LEFT")
        style = [("GRID", (0, 0), (-1, -1), 0.3, colors.grey), ("VALIGN", (0, 0), (-1, -1), "TOP"),
                 ("FONT", (0, 0), (-1, -1), cell.fontName, cell.fontSize, cell.leading)]  # fmt: skip
        if header:
            style.append(("BACKGROUND", (0, 0), (-1, 0), colors.Color(0.92, 0.92, 0.92)))
        t.setStyle(TableStyle(style))
        return t

    def section(title: str) -> Paragraph:
        return Paragraph(pdf_text(title), styles["Heading3"])

    story += [section("1. Identification"), tbl(None, cert.identification, [55 * mm, 125 * mm])]
    story += [section("2. Dates"), tbl(None, cert.dates, [55 * mm, 125 * mm])]
    story += [section(CONDITIONS), tbl(None, [*cert.conditions, *cert.environment], [55 * mm, 125 * mm])]
    story.append(section("4. Results (expanded uncertainty U = k u, coverage probability about 95 %)"))
    story.append(tbl(RESULT_HEADER, [r.cells() for r in cert.results]))
    story.append(Paragraph(f"<b>Decision rule.</b> {pdf_text(cert.decision_rule)}", small))
    for r in cert.remarks:
        story.append(Paragraph(pdf_text(r), small))
    if cert.papers:
        story.append(Paragraph(f"<b>Papers cited</b> ({PAPERS_NOTE})", small))
        story += [Paragraph(pdf_text(p), small) for p in cert.papers]
    story.append(section("5. Traceability of the references"))
    story.append(tbl(("quantity", "standard uncertainty", "traceability"),
                     [(t["quantity"], t["standard_uncertainty"], t["traceability"]) for t in cert.traceability],
                     [50 * mm, 28 * mm, 102 * mm]))  # fmt: skip
    story.append(section("6. Uncertainty budget (GUM, JCGM 100:2008)"))
    for title, header, rows in cert.budgets:
        story += [Paragraph(f"<b>{pdf_text(title)}</b>", small), tbl(header, rows)]
    for i, (title, header, rows) in enumerate(cert.extra_tables):
        story += [section(f"{7 + i}. {title}"), tbl(header, rows)]
    first = 7 + len(cert.extra_tables)
    for i, (caption, make) in enumerate(cert.figures):
        png, aspect = _png(make())
        width = 180 * mm
        story.append(KeepTogether([section(f"{first}. Figures" if i == 0 else "Figures (continued)"),
                                   Paragraph(pdf_text(caption), small),
                                   Image(io.BytesIO(png), width=width, height=width * aspect)]))  # fmt: skip
    sig_rows = [(f"{s}:", "name ____________________", "signature ____________________", "date __________")
                for s in cert.signatures]  # fmt: skip
    story.append(KeepTogether([section("Signatures"), Spacer(1, 4 * mm), tbl(None, sig_rows),
                               Paragraph("This certificate shall not be reproduced except in full without the "
                                         "written approval of the laboratory. The results relate only to the "
                                         "item calibrated.", small)]))  # fmt: skip
    doc = SimpleDocTemplate(buf, pagesize=A4, leftMargin=15 * mm, rightMargin=15 * mm, topMargin=18 * mm,
                            bottomMargin=18 * mm, title=cert.title, author=lab["name"])  # fmt: skip

    def maker(*a, **k):
        return _NumberedCanvas(*a, cert_id=cert.certificate_id, simulated=cert.simulated, **k)

    doc.build(story, canvasmaker=maker)
    return buf.getvalue()


def _pdf_cell(text: str, style: ParagraphStyle) -> Paragraph | str:
    """A table cell of the PDF: a short one (a number, an interval, a number with its unit) as one unbroken line,
    a longer text as a paragraph that wraps."""
    return pdf_chars(text) if len(text) <= UNBROKEN_CELL else Paragraph(pdf_text(text), style)
