"""Training loops (separator pretraining, PPO) on the in-process vectorized environment."""
