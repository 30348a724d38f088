"""Small helpers every layer may use: the paper's defaults, CSV and plot output."""
