"""What the host computes from stored models: synthesis (`synth`, `fields`), interpolation
over angles (`interpolation`), the paper's metrics and Table 2 (`metrics`, `pdfs`,
`level_bins`), the resolution rule (`resolve`), radiometry and row tiles (`tiles`).
"""
