"""Identification of the linear parts of a loop from closed-loop data, and oscillation
detection.
"""
