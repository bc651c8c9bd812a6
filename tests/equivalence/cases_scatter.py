"""Equivalence cases of the Bezier scatter (seed 003); `cases.CASES` includes them."""

from __future__ import annotations

CASES: list = []
