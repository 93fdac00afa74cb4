"""Sim-to-real gap diagnosis (issue 3): where a recorded session and the twin disagree, and why.

Entry points: `gap.api.diagnose` (a GapReport; `.to_json()`),
`gap.report.render` (the HTML report), `station gap` and
`station gap-validate` (gap.validate).
"""
