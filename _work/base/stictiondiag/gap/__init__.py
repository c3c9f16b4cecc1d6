"""The sim-to-real gap: where the replay departs from the data, and which unmodelled
effect explains it.
"""
