"""The paper's approximate apex return map (section II).

- :mod:`.apex_map`: the map's object API, with its derivation; its compiled kernels are :mod:`.map_kernels`;
- :mod:`.closed_loop`: the map closed by a policy, its Jacobian (complex step) and eigenvalues.

The public names below are imported on first use (``__init__.pyi`` declares them).
"""

import lazy_loader

__getattr__, __dir__, __all__ = lazy_loader.attach_stub(__name__, __file__)
