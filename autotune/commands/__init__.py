"""The ``autotune`` subcommands that exist without a study (``train``, ``evaluate``): parse and print only."""
