"""Uplink models shared by the device, the simulator and the learner: Markov and trace channels."""
