"""Public names of :mod:`tdslip_ros.model.stability`, imported lazily (``__init__.py``)."""

from .analytic_accuracy import (
    Accuracy as Accuracy,
)
from .analytic_accuracy import (
    accuracy as accuracy,
)
from .analytic_accuracy import (
    domain_table as domain_table,
)
from .analytic_fixed_points import (
    FixedPoints as FixedPoints,
)
from .analytic_fixed_points import (
    energy_fixed_point as energy_fixed_point,
)
from .analytic_fixed_points import (
    open_loop_fixed_points as open_loop_fixed_points,
)
from .analytic_fixed_points import (
    regulated_fixed_points as regulated_fixed_points,
)
from .basins import (
    Basin as Basin,
)
from .basins import (
    basin as basin,
)
from .basins import (
    open_loop_basin as open_loop_basin,
)
from .basins import (
    regulated_basin as regulated_basin,
)
from .basins import (
    run_strides as run_strides,
)
from .exact_fixed_points import ExactLoop as ExactLoop
from .viability import QMap as QMap
from .viability import ViabilityResult as ViabilityResult
from .viability import viable_set as viable_set
from .viability_spaces import ApexSpace as ApexSpace
from .viability_spaces import EnergySpace as EnergySpace
from .viability_spaces import q_map as q_map
