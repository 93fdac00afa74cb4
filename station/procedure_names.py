"""Procedure names across versions: the core's one declaration of the names earlier versions stored.

Before issue 29 procedures were registered under the seed paper that describes them ("seed000.integral_precession");
they are now named after their packages ("integral_precession"). Sessions stored and procedure files written under
a former name still name the same procedure: the engine resolves them (station.engine.registry.get_procedure), and
the histories (a station's store through the panel, the central database) list them under either name.
"""

from __future__ import annotations

# former name -> current name
FORMER_NAMES: dict[str, str] = {
    "seed000.integral_precession": "integral_precession",
    "seed000.integer_periodic_vibration": "integral_precession.integer_periodic_vibration",
    "seed000.multi_frequency": "integral_precession.multi_frequency",
    "seed000.planning": "integral_precession.planning",
    "seed000.self_alignment": "integral_precession.self_alignment",
    "seed000.parasitic_translation": "integral_precession.parasitic_translation",
    "seed000.frequency_stability": "integral_precession.frequency_stability",
    "seed000.parasitic_rotation": "integral_precession.parasitic_rotation",
    "seed001.tumble": "tumble",
    "seed002.g_sensitive_misalignment": "rlg_g_sensitivity",
    "seed003.gravity_field": "multiposition",
    "seed003.planning": "multiposition.planning",
    "seed004.nonlinear_suppression": "nonlinear_suppression",
}


def current_name(name: str) -> str:
    """The procedure's name today, whichever name a session or a file stored."""
    return FORMER_NAMES.get(name, name)


def stored_names(name: str) -> tuple[str, ...]:
    """Every name a session of this procedure may be stored under: today's and the former ones, today's first."""
    today = current_name(name)
    return (today, *sorted(old for old, new in FORMER_NAMES.items() if new == today))
