"""The papers' systems as reusable computations behind their reports (tables, figures, Monte Carlo studies).

One module per paper; each composes components of the other packages and
returns plain numbers and arrays — the report commands print and plot them.
"""
