"""Stability: fixed points and their eigenvalues, basins of attraction, where the analytic map is accurate,
viability.

- :mod:`.analytic_fixed_points`: the analytic map's fixed points (sections III-IV);
- :mod:`.exact_fixed_points`: the same construction on the exact plant;
- :mod:`.basins`: closed-loop runs of many strides and their basins;
- :mod:`.analytic_accuracy`: the analytic map against the exact plant over its domain;
- :mod:`.viability`: viable sets, kernels and measures of a Q-map (:mod:`.viability_spaces`: its spaces).

The public names below are imported on first use (``__init__.pyi`` declares them).
"""

import lazy_loader

__getattr__, __dir__, __all__ = lazy_loader.attach_stub(__name__, __file__)
