"""udt_node: the user digital twin — uplink channel models, latent inference, baselines."""
