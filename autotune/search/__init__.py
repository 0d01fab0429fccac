"""The study: spec (TOML → frozen dataclasses), search spaces, the trial objective (no Optuna, no Ray), the
Optuna driver (the only module importing optuna), the Ray workers (the only module importing ray),
storage and read-only trial records. Imports ``sim``, ``autotune.convnet`` and ``autotune.learner``.
"""
