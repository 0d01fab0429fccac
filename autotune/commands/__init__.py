"""Every ``autotune`` subcommand, one module each: parse the arguments, call library code, print.

``train`` and ``evaluate`` (one net; ``evaluate --trial`` reproduces a study's trial), ``launch`` (run or
resume a study), ``inspect`` (``status``, ``best``, ``dashboard``), ``crowd`` (``crowd import``,
``crowd replay``), ``compare`` (the report) and ``replay`` (one run drawn). Each exposes
``add_parser(subparsers)`` and ``run(args) -> int``; ``autotune.cli.SUBCOMMANDS`` lists them. Bad
input is raised as a ``ConfigError`` and ``autotune.cli.main`` alone turns it into one line and exit
status 2. The only layer besides ``autotune.cli`` that may import ``dashboards``.
"""
