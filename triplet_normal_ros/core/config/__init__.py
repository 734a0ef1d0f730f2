"""The settings and the plan: conventions, defaults, the settings and their rules, device names and which path a
cloud takes. Pure Python (no torch, no numba, no look at the data), so the CLI and the node read the rules without
loading the estimator (test_layers)."""
