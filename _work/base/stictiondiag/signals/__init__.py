"""Signal analysis below the models: oscillation detection by the autocorrelation
zero-crossing method.
"""
