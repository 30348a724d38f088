"""The paper's experiments: the twin's Figs 3–5 (``twin``) and map management's Figs 7–9
(``amm``)."""
