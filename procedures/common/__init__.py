"""What the procedures share: uncertainty budgets, certificates and the reference standards they cite."""
