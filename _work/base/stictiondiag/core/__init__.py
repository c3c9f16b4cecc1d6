"""Foundations every layer may use: errors and exit codes, compiled-kernel helper, filters,
scalar optimisation, statistics, whole-or-nothing file output, JSON conversion, robust spread.
"""
