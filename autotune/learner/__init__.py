"""deepqlearn: the DQN and the DeepTraffic training protocol, quick and exact official evaluation of a net,
and the float64 replica of the original learner kept as the executable reference (``js_learner``).

Imports ``sim`` and ``autotune.convnet`` only; never the search, optuna or ray. Import the
submodules directly (``autotune`` re-exports the public names lazily).
"""
