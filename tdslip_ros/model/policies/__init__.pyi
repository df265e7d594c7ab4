"""Public names of :mod:`tdslip_ros.model.policies`, imported lazily (``__init__.py``)."""

from .controllers import (
    admissible_angles as admissible_angles,
)
from .controllers import (
    apex_foot_placement as apex_foot_placement,
)
from .controllers import (
    deadbeat as deadbeat,
)
from .controllers import (
    energy_regulation as energy_regulation,
)
from .controllers import (
    exact_energy_regulation as exact_energy_regulation,
)
from .controllers import (
    fixed_power as fixed_power,
)
from .controllers import (
    ramp_to_liftoff as ramp_to_liftoff,
)
from .learned import LinearResidual as LinearResidual
from .registry import (
    POLICIES as POLICIES,
)
from .registry import (
    POLICY_SETTINGS as POLICY_SETTINGS,
)
from .registry import (
    STANCE_FEEDBACK_POLICIES as STANCE_FEEDBACK_POLICIES,
)
from .registry import (
    PolicyError as PolicyError,
)
from .registry import (
    PolicySetting as PolicySetting,
)
from .registry import (
    PolicySpec as PolicySpec,
)
from .registry import (
    check_policy_file as check_policy_file,
)
from .registry import (
    settings_of as settings_of,
)
from .stance_pd import StancePDSpeedEnergy as StancePDSpeedEnergy
