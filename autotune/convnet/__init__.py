"""convnetjs networks: layer specs (``spec``), the torch bridge, JSON / net.js I/O (``netjson``), the exact
float64 forward pass (``forward``) and convnetjs's random routines (``random``).

Imports only ``sim`` below it; never the learner or the search. Import the submodules directly.
"""
