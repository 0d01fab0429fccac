"""convnetjs networks: layer specs (``spec``), the torch bridge (``torch_bridge``), JSON / net.js I/O
(``netjson``), the exact float64 forward pass (``forward``), convnetjs's random routines (``random``)
and deepqlearn's decision rules (``deepqlearn``) shared by every fast path.

Imports only ``sim`` below it; never the learner or the search. Import the submodules directly.
"""
