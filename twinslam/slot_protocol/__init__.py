"""The slot protocol's constants: the paper's Table I defaults and the rule of a lost frame,
which the nodes, the simulator and the learning share."""
