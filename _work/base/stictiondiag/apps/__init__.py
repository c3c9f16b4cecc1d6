"""Applications built on the analysis: reports, plant scans, ISDB validation, the
withheld-effect benchmark.
"""
