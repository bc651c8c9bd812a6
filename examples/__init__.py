"""Worked examples of diffblur in training code (run as `python -m examples.<name>`)."""
