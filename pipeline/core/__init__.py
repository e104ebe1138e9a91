"""The algorithms: world model, features, controllers, graph MDP, adaptive state graph,
reference roadmap, experts, social metrics, policy loss. Plain numpy/scipy/scikit-learn:
no Hydra, no MCAP, no file I/O, so every piece can be tested and reused alone."""
