"""stictiondiag: diagnose control-valve stiction from plant data.

The science is Choudhury, Thornhill & Shah (2005), "Modelling valve stiction",
Control Engineering Practice 13, 641-658.

Public names are loaded lazily (PEP 562): ``import stictiondiag`` costs almost
nothing, and the first access to a name imports only the submodule that defines it,
so the ``stiction`` command does not pay for numpy, pandas, numba or scipy before it
needs them.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # static analysers and IDEs see the eager imports
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

# public name -> submodule that defines it
_LAZY: dict[str, str] = {
    "atomic_path": "atomic",
    "write_atomic": "atomic",
    "BicoherenceResult": "baselines",
    "HorchResult": "baselines",
    "bicoherence_indices": "baselines",
    "choudhury_hos_diagnosis": "baselines",
    "horch_cross_correlation": "baselines",
    "LimitCyclePrediction": "describing",
    "describing_function": "describing",
    "describing_function_numeric": "describing",
    "predict_limit_cycle": "describing",
    "EFFECT_MODELS": "effects",
    "EFFECTS": "effects",
    "valve_replay": "effects",
    "DataError": "errors",
    "StictionError": "errors",
    "UsageError": "errors",
    "StictionFit": "estimate",
    "Verdict": "estimate",
    "stiction_verdict": "estimate",
    "GapDiagnosis": "gap",
    "diagnose_gap": "gap",
    "fit_hammerstein": "hammerstein",
    "ControllerFit": "identify",
    "ProcessFit": "identify",
    "controller_fit": "identify",
    "identify_controller": "identify",
    "identify_process": "identify",
    "process_fit": "identify",
    "LimitCycle": "loops",
    "Simulation": "loops",
    "simulate_loop": "loops",
    "simulate_paper_loop": "loops",
    "Oscillation": "oscillation",
    "detect_oscillation": "oscillation",
    "dominant_period": "oscillation",
    "VALVE_PARAMETERS": "physical",
    "PhysicalValve": "physical",
    "karnopp": "physical",
    "Replay": "replay",
    "Segments": "segments",
    "estimate_from_mv": "segments",
    "segment_valve": "segments",
    "Tags": "tags",
    "read_frame": "tags",
    "read_tags": "tags",
    "scale": "tags",
    "STICTION_MODEL_PARAMETERS": "valve",
    "choudhury_model": "valve",
    "ewma": "valve",
    "kano_model": "valve",
    "ma_to_percent": "valve",
    "percent_to_ma": "valve",
    "valve_characteristic": "valve",
}


def __getattr__(name: str) -> Any:
    """Import the submodule behind a public name (or a submodule) on first access."""
    module = _LAZY.get(name)
    if module is not None:
        value = getattr(importlib.import_module(f".{module}", __name__), name)
        globals()[name] = value  # later look-ups skip this function
        return value
    if not name.startswith("__"):
        try:
            return importlib.import_module(f".{name}", __name__)
        except ModuleNotFoundError as exc:
            if exc.name != f"{__name__}.{name}":
                raise
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
