"""Public names of :mod:`tdslip_ros.model.plant`, imported lazily (``__init__.py``)."""

from .batch import (
    BatchRun as BatchRun,
)
from .batch import (
    BatchStrideResult as BatchStrideResult,
)
from .batch import (
    batch_apex_return_map as batch_apex_return_map,
)
from .batch import (
    batch_feedback_return_map as batch_feedback_return_map,
)
from .batch import (
    simulate_strides as simulate_strides,
)
from .exact_map import (
    StrideResult as StrideResult,
)
from .exact_map import (
    apex_return_map as apex_return_map,
)
from .perturbations import (
    Mismatch as Mismatch,
)
from .perturbations import (
    Perturbations as Perturbations,
)
from .perturbations import (
    PlacementNoise as PlacementNoise,
)
from .perturbations import (
    Pushes as Pushes,
)
from .perturbations import (
    SensingNoise as SensingNoise,
)
from .stance_laws import (
    RecordedTorques as RecordedTorques,
)
from .stance_laws import (
    StanceFeedback as StanceFeedback,
)
from .stance_laws import (
    StanceLaw as StanceLaw,
)
from .stance_laws import (
    StanceSample as StanceSample,
)
from .stance_laws import (
    TorqueStream as TorqueStream,
)
from .stepper import FixedStepStepper as FixedStepStepper
from .stride_kernels import (
    LaneStrideResult as LaneStrideResult,
)
from .stride_kernels import (
    apex_stride as apex_stride,
)
from .stride_kernels import (
    compiled_apex_return_map as compiled_apex_return_map,
)
from .terrain import (
    Blocks as Blocks,
)
from .terrain import (
    Flat as Flat,
)
from .terrain import (
    Profile as Profile,
)
from .terrain import (
    Step as Step,
)
from .terrain import (
    Terrain as Terrain,
)
from .terrain import (
    parse_terrain as parse_terrain,
)
