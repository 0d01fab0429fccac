"""The study: ``spec`` (TOML → frozen dataclasses; parses only), ``space`` (parameters ↔ configurations,
and the last check of a spec), ``objective`` (one trial: train, report, score — no Optuna, no Ray),
``driver`` (the Optuna study: ask/tell, pruning, retries, resume, warm start), ``ladder`` (the budget
ladder), ``cost`` / ``gate`` (the cost model and the sampler wrapper that refuses what it cannot pay
for), ``racing`` (the seed race), ``workers`` (the only module importing ray), ``storage`` (journal /
SQL storages and the artifact store), ``keys`` (the names trial records are stored under), ``records``
(the one read API: plain ``StudyRecord`` / ``TrialRecord`` data, summaries, exports, reproductions),
``enqueue`` (trials from outside the sampler: imported finished trials, enqueued full configurations)
and ``dashboard`` (optuna-dashboard: serving, attaching figures).

Optuna is imported only inside this package; ``dashboards`` and ``autotune.commands`` read studies as
plain records. Imports ``sim``, ``autotune.convnet`` and ``autotune.learner``.
"""
