"""stictiondiag: diagnose control-valve stiction from plant data.

The science is Choudhury, Thornhill & Shah (2005), "Modelling valve stiction",
Control Engineering Practice 13, 641-658.
"""

from .atomic import atomic_path, write_atomic
from .baselines import (
    BicoherenceResult,
    HorchResult,
    bicoherence_indices,
    choudhury_hos_diagnosis,
    horch_cross_correlation,
)
from .describing import (
    LimitCyclePrediction,
    describing_function,
    describing_function_numeric,
    predict_limit_cycle,
)
from .effects import EFFECT_MODELS, EFFECTS, valve_replay
from .errors import DataError, StictionError, UsageError
from .estimate import StictionFit, Verdict, stiction_verdict
from .gap import GapDiagnosis, diagnose_gap
from .hammerstein import fit_hammerstein
from .identify import (
    ControllerFit,
    ProcessFit,
    controller_fit,
    identify_controller,
    identify_process,
    process_fit,
)
from .loops import LimitCycle, Simulation, simulate_loop, simulate_paper_loop
from .oscillation import Oscillation, detect_oscillation, dominant_period
from .physical import VALVE_PARAMETERS, PhysicalValve, karnopp
from .replay import Replay
from .segments import Segments, estimate_from_mv, segment_valve
from .tags import Tags, read_frame, read_tags, scale
from .valve import (
    STICTION_MODEL_PARAMETERS,
    choudhury_model,
    ewma,
    kano_model,
    ma_to_percent,
    percent_to_ma,
    valve_characteristic,
)

__version__ = "0.1.0"

__all__ = [
    "DataError",
    "StictionError",
    "UsageError",
    "STICTION_MODEL_PARAMETERS",
    "choudhury_model",
    "kano_model",
    "ewma",
    "ma_to_percent",
    "percent_to_ma",
    "valve_characteristic",
    "Tags",
    "read_frame",
    "read_tags",
    "scale",
    "atomic_path",
    "write_atomic",
    "Oscillation",
    "detect_oscillation",
    "dominant_period",
    "LimitCyclePrediction",
    "describing_function",
    "describing_function_numeric",
    "predict_limit_cycle",
    "HorchResult",
    "BicoherenceResult",
    "horch_cross_correlation",
    "bicoherence_indices",
    "choudhury_hos_diagnosis",
    "LimitCycle",
    "Simulation",
    "simulate_loop",
    "simulate_paper_loop",
    "VALVE_PARAMETERS",
    "PhysicalValve",
    "karnopp",
    "ControllerFit",
    "ProcessFit",
    "controller_fit",
    "identify_controller",
    "identify_process",
    "process_fit",
    "Replay",
    "EFFECTS",
    "EFFECT_MODELS",
    "valve_replay",
    "GapDiagnosis",
    "diagnose_gap",
    "StictionFit",
    "Verdict",
    "stiction_verdict",
    "Segments",
    "segment_valve",
    "estimate_from_mv",
    "fit_hammerstein",
]
