"""BIRL-G: Bayesian inverse reinforcement learning over adaptive state graphs.

Reference implementation of Okal, Gilbert, Arras, *Efficient Inverse Reinforcement
Learning using Adaptive State-Graphs*, as a reproducible five-stage Hydra pipeline.
"""

__version__ = "0.1.0"
