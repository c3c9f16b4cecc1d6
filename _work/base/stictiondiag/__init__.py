"""stictiondiag: diagnose control-valve stiction from plant data.

The science is Choudhury, Thornhill & Shah (2005), "Modelling valve stiction",
Control Engineering Practice 13, 641-658.

Start with :func:`analyze` (or :func:`analyze_file`): one loop's tags in, an
:class:`Analysis` out.

Public names are loaded lazily (PEP 562): ``import stictiondiag`` imports no numpy,
so a program (the ``stiction`` command among them) can set numpy's thread settings
(:mod:`stictiondiag.core.blas`) after importing this package and before numpy loads;
the first access to a name imports only the submodule that defines it.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # static analysers and IDEs see the eager imports
    from stictiondiag.analysis import (
        AnalysisConfig,
        LoopEstimate,
        analyze,
        analyze_file,
        diagnose_gap_file,
        diagnose_gap_tags,
        estimate_loop,
        run_from_estimate,
    )
    from stictiondiag.core.atomic import (
        atomic_path,
        write_atomic,
    )
    from stictiondiag.core.errors import (
        DataError,
        StictionError,
        UsageError,
    )
    from stictiondiag.gap.diagnose import (
        GapDiagnosis,
        diagnose_gap,
    )
    from stictiondiag.gap.effects import (
        EFFECT_MODELS,
        EFFECTS,
        valve_replay,
    )
    from stictiondiag.identification.controller import (
        ControllerFit,
        controller_fit,
        identify_controller,
    )
    from stictiondiag.identification.process import (
        ProcessFit,
        identify_process,
        process_fit,
    )
    from stictiondiag.io.tags import (
        Tags,
        read_frame,
        read_tags,
        scale,
    )
    from stictiondiag.models.describing import (
        LimitCyclePrediction,
        describing_function,
        describing_function_numeric,
        predict_limit_cycle,
    )
    from stictiondiag.models.loops import simulate_loop, simulate_paper_loop
    from stictiondiag.models.physical import (
        VALVE_PARAMETERS,
        PhysicalValve,
        karnopp,
    )
    from stictiondiag.models.simulation import LimitCycle, Simulation
    from stictiondiag.models.valve import (
        STICTION_MODEL_PARAMETERS,
        choudhury_model,
        ewma,
        kano_model,
        ma_to_percent,
        percent_to_ma,
        valve_characteristic,
    )
    from stictiondiag.replay.closed_loop import Replay
    from stictiondiag.result import Analysis
    from stictiondiag.signals.oscillation import (
        Oscillation,
        detect_oscillation,
        dominant_period,
    )
    from stictiondiag.stiction.classic import (
        BicoherenceResult,
        HorchResult,
        bicoherence_indices,
        choudhury_hos,
        horch_cross_correlation,
    )
    from stictiondiag.stiction.hammerstein import fit_hammerstein
    from stictiondiag.stiction.segments import (
        Segments,
        estimate_from_mv,
        segment_valve,
    )
    from stictiondiag.stiction.valvefit import Determinacy, StictionFit
    from stictiondiag.stiction.verdict import (
        Verdict,
        stiction_verdict,
    )

__version__ = "0.1.0"

__all__ = [
    "Analysis",
    "AnalysisConfig",
    "analyze",
    "analyze_file",
    "LoopEstimate",
    "estimate_loop",
    "run_from_estimate",
    "diagnose_gap_tags",
    "diagnose_gap_file",
    "Determinacy",
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
    "choudhury_hos",
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
    "Analysis": "result",
    "AnalysisConfig": "analysis",
    "analyze": "analysis",
    "analyze_file": "analysis",
    "LoopEstimate": "analysis",
    "estimate_loop": "analysis",
    "run_from_estimate": "analysis",
    "diagnose_gap_tags": "analysis",
    "diagnose_gap_file": "analysis",
    "Determinacy": "stiction.valvefit",
    "atomic_path": "core.atomic",
    "write_atomic": "core.atomic",
    "BicoherenceResult": "stiction.classic",
    "HorchResult": "stiction.classic",
    "bicoherence_indices": "stiction.classic",
    "choudhury_hos": "stiction.classic",
    "horch_cross_correlation": "stiction.classic",
    "LimitCyclePrediction": "models.describing",
    "describing_function": "models.describing",
    "describing_function_numeric": "models.describing",
    "predict_limit_cycle": "models.describing",
    "EFFECT_MODELS": "gap.effects",
    "EFFECTS": "gap.effects",
    "valve_replay": "gap.effects",
    "DataError": "core.errors",
    "StictionError": "core.errors",
    "UsageError": "core.errors",
    "StictionFit": "stiction.valvefit",
    "Verdict": "stiction.verdict",
    "stiction_verdict": "stiction.verdict",
    "GapDiagnosis": "gap.diagnose",
    "diagnose_gap": "gap.diagnose",
    "fit_hammerstein": "stiction.hammerstein",
    "ControllerFit": "identification.controller",
    "ProcessFit": "identification.process",
    "controller_fit": "identification.controller",
    "identify_controller": "identification.controller",
    "identify_process": "identification.process",
    "process_fit": "identification.process",
    "LimitCycle": "models.simulation",
    "Simulation": "models.simulation",
    "simulate_loop": "models.loops",
    "simulate_paper_loop": "models.loops",
    "Oscillation": "signals.oscillation",
    "detect_oscillation": "signals.oscillation",
    "dominant_period": "signals.oscillation",
    "VALVE_PARAMETERS": "models.physical",
    "PhysicalValve": "models.physical",
    "karnopp": "models.physical",
    "Replay": "replay.closed_loop",
    "Segments": "stiction.segments",
    "estimate_from_mv": "stiction.segments",
    "segment_valve": "stiction.segments",
    "Tags": "io.tags",
    "read_frame": "io.tags",
    "read_tags": "io.tags",
    "scale": "io.tags",
    "STICTION_MODEL_PARAMETERS": "models.valve",
    "choudhury_model": "models.valve",
    "ewma": "models.valve",
    "kano_model": "models.valve",
    "ma_to_percent": "models.valve",
    "percent_to_ma": "models.valve",
    "valve_characteristic": "models.valve",
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
