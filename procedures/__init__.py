"""The calibration methods: one package per seed paper (procedures, analysis, reports), common/ for what they share."""
