"""Models of the paper: data-driven and physical valves (Sections 4-5), processes and
controllers (Table 3), closed loops (Eq. 3), the describing function (Section 6), and
the generated loops of the withheld-effect benchmark.
"""
