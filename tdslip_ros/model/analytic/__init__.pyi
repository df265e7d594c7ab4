"""Public names of :mod:`tdslip_ros.model.analytic`, imported lazily (``__init__.py``)."""

from .apex_map import (
    Stance as Stance,
)
from .apex_map import (
    Stride as Stride,
)
from .apex_map import (
    approximate_map as approximate_map,
)
from .apex_map import (
    approximate_return_map as approximate_return_map,
)
from .apex_map import (
    descent_map as descent_map,
)
from .apex_map import (
    stance_map as stance_map,
)
from .closed_loop import (
    closed_loop_map as closed_loop_map,
)
from .closed_loop import (
    eigenvalues as eigenvalues,
)
from .closed_loop import (
    fixed_command as fixed_command,
)
from .closed_loop import (
    map_jacobian as map_jacobian,
)
