"""The controllers: what to command at an apex (a ramp), or during stance (a sampled law).

- :mod:`.registry`: the policies by name and **the one declaration of every policy setting**
  (``POLICY_SETTINGS``);
- :mod:`.controllers`: the vectorised policies planned on the analytic map, with their compiled kernels
  :mod:`.controller_kernels` and :mod:`.deadbeat_kernels`; ``energy_exact``'s planner on the exact plant,
  :mod:`.exact_regulation_kernels`;
- :mod:`.stance_pd`: the stance PD law of the paper's ref. 36;
- :mod:`.learned`: the learned linear residual on a base policy.

The public names below are imported on first use (``__init__.pyi`` declares them).
"""

import lazy_loader

__getattr__, __dir__, __all__ = lazy_loader.attach_stub(__name__, __file__)
