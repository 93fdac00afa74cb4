"""Sim-to-real gap diagnosis (issue 3): where a recorded session and the twin disagree, and why.

Entry points: `station.gap.api.diagnose` (a GapReport; `.to_json()`),
`station.gap.report.render` (the HTML report), `station gap` and
`station gap-validate` (station.gap.validate).
"""
