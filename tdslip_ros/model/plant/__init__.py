"""The exact plant: the TD-SLIP equations of :mod:`tdslip_ros.model.dynamics` integrated with events located
inside the step, and what perturbs a stride.

- :mod:`.exact_map`: one apex to the next, DOP853 with dense-output event location (the reference);
- :mod:`.stepper`: the 1 kHz fixed-step plant of the plant node; :mod:`.stepper_bounds`, what it accepts, and
  :mod:`.flight_landing`, where one of its flights lands;
- :mod:`.batch` (with :mod:`.batch_stance` and the integrator :mod:`.stance_kernel`): many apexes at once;
- :mod:`.stride_kernels`: the batched engine's ramp stride compiled for one lane;
- :mod:`.stance_laws`: the interface of a hip torque decided during stance (the laws themselves are policies);
- :mod:`.terrain`, :mod:`.perturbations`: the ground and the per-stride perturbations.

The public names below are imported on first use (``__init__.pyi`` declares them), so that a node that needs
only the stepper does not load scipy.integrate and numba.
"""

import lazy_loader

__getattr__, __dir__, __all__ = lazy_loader.attach_stub(__name__, __file__)
