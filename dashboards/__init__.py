"""Reports and the crowd, above the search: plot data extracted first (``extract``, ``insights``, ``spread``),
then plotly figures (``figures``, ``report``); the crowd sample (``crowd_data``), the crowd as a study
(``crowd``), its ``--filter`` (``crowd_filter``), its retraining (``crowd_replay``) and the settings a study
tries first (``crowd_prior``); one evaluation run
recorded (``replay``) and drawn (``replay_render``).

Reads studies only through ``autotune.search.records`` (plain records) and writes them only through
``autotune.search.enqueue`` / ``autotune.search.dashboard``: never imports optuna, ray or torch.
"""
