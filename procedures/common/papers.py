"""The seed papers the methods implement, as a certificate cites them in full (docs/references.md carries the same
citations, tests/test_docs.py checks it): the code, reports and certificates call them "seed 000" .. "seed 004"
and number equations, tables and figures as the paper does. What a paper's text does not give is said to be
missing, not guessed."""

from __future__ import annotations

import re
from collections.abc import Iterable

PAPERS = {
    "000": "C. Sun, S.-q. Ren, J.-w. Cao, R. Huo: Integral precession calibration method of PIGA on linear "
    "vibration table. Chinese Journal of Aeronautics (Elsevier), accepted 23 July 2023; volume, pages and DOI not "
    "in the text.",
    "001": "Calibration of navigation pendulous accelerometer by testing rotating method in terrestrial "
    "gravitational field, 2009 (received 10.12.2009); authors, journal, volume, pages and DOI not in the text.",
    "002": "L. Wang, W. Wu, G. Li, X. Pan, R. Yu: Ring Laser Gyro G-Sensitive Misalignment Calibration in Linear "
    "Vibration Environments. MDPI, Basel, published 16 February 2018; journal, volume, pages and DOI not in the "
    "text.",
    "003": "The calibration method of the main error coefficients of PIGA on the indexing head table, with the "
    "orthogonal 4-pose calibration of dual PIGAs and a 22-position optimal calibration; title, authors, journal, "
    "year, volume, pages and DOI not in the text (cited by its abstract).",
    "004": "Analysis and Suppression of Nonlinear Error of Pendulous Integrating Gyroscopic Accelerometer at "
    "Instrument Level. Sensors 2023, 23(3), 1221, doi:10.3390/s23031221; authors not in the text.",
}
SEED_CITED = re.compile(r"\bseed (\d{3})\b", re.I)


def papers_cited(texts: Iterable[str]) -> list[str]:
    """'seed NNN: citation' of every seed paper the texts name, in order of the number."""
    seeds = sorted({n for text in texts for n in SEED_CITED.findall(text)} & set(PAPERS))
    return [f"seed {n}: {PAPERS[n]}" for n in seeds]
