"""An independent generator of piga-session/1 sessions (issue 10, deliverables 4 and 5).

Written from docs/physics.md (the physics reference) alone: it imports nothing from this project (only numpy,
scipy and the standard library), so the gap diagnosis can be scored on data that the twin did
not make. Modules: `world` (table motion, inputs, rate model, first passage, stamps, raw
records), `generator` (designs, instruments, sessions, the writer), `effects` (library and
out-of-library perturbations, signatures, SNR scaling), `cases` (the contract the gap
diagnosis is scored against, and a batch CLI).
"""
