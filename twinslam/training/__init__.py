"""Training the learned policy (Algorithm 2): real slots of the simulator's world blended with
artificial ones a rate model generates (``trainer.py``); the actor it trains is
:mod:`twinslam.policies.learned`."""
