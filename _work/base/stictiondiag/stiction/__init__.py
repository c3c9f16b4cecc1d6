"""Stiction estimation: S and J from mv segments or a Hammerstein fit, and the verdict
(Section 5.3), beside the classic data-driven tests.
"""
