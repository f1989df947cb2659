"""Condition monitoring: residuals, spectra, features, health model and alarms."""
